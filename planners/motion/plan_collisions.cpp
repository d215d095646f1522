#include "motion/plan_collisions.hpp"

#include <algorithm>

#include "collision/triangle_bvh.hpp"
#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "port_placement/port_rules.hpp"

namespace trocar::planners {

PlanCollisions::PlanCollisions(const patient::PatientModel& patient,
                               std::shared_ptr<const robot::RobotModel> robot, const PlanFile& file,
                               std::size_t plan_index) {
  TROCAR_THROW_UNLESS(plan_index < file.plans.size(),
                      file.path << ": has " << file.plans.size() << " plans, not " << plan_index + 1);
  const StoredPlan& plan = file.plans[plan_index];
  collision::WorldOptions options;
  for (const StoredArm& arm : file.arms) {
    if (arm.rcm_frame.empty()) {
      TROCAR_THROW_UNLESS(!arm.shaft_link.empty(), file.path << ": arm " << arm.name
                                                             << " has neither an RCM frame nor a shaft link");
      options.shaft_ports.push_back(arm.shaft_link);
    }
  }
  robot_ = robot;
  world_ = collision::CollisionWorld::Build(&patient, std::move(robot), options);
  checker_ = std::make_unique<collision::CollisionChecker>(world_);
  // Each arm's port: RCM ports by frame, shaft ports after them in arm order.
  int shaft = 0;
  for (const auto& port : world_->ports()) shaft += port.frame.empty() ? 0 : 1;
  if (const patient::Structure* s = patient.Find("skin"); s && !s->mesh.triangles.empty())
    skin_ = std::make_unique<collision::TriangleBvh>(s->mesh);
  const Eigen::Isometry3d X_PW = patient.X_WP.inverse();
  X_PW_ = X_PW;
  for (std::size_t a = 0; a < file.arms.size(); ++a) {
    const std::string& rcm = file.arms[a].rcm_frame;
    int index = rcm.empty() ? shaft++ : -1;
    for (std::size_t p = 0; p < world_->ports().size() && !rcm.empty(); ++p)
      if (world_->ports()[p].frame == rcm) index = static_cast<int>(p);
    TROCAR_THROW_UNLESS(index >= 0, file.path << ": arm " << file.arms[a].name << ": RCM frame '"
                                              << rcm << "' is not a port of the robot");
    port_of_arm_.push_back(index);
    double depth = 0.0;
    const Eigen::Vector3d pivot_P = X_PW * plan.ports[a].rcm_W;
    if (skin_) {
      const auto c = skin_->Closest(pivot_P, pivot_P);
      if (c.found()) depth = c.distance;
    }
    allowance_.push_back(PortTrackLength(depth, pivot_P, X_PW * plan.ports[a].p_W) +
                         world_->options().port_radius);
    depth_.push_back(depth);
    incisions_P_.push_back(X_PW * plan.ports[a].p_W);
    const std::string& tool = file.arms[a].tool_frame;
    robot::Frame tool_frame;  // link -1: none
    if (!tool.empty()) {
      try {
        tool_frame = robot_->GetFrame(tool);
      } catch (const Error& e) {
        TROCAR_THROW(file.path << ": robot.arms[" << a << "].tool_frame: " << e.what());
      }
    }
    tool_frame_.push_back(tool_frame);
  }
  pivots_.reserve(plan.ports.size());
  for (const StoredPort& port : plan.ports) pivots_.push_back(port.rcm_W);
  for (const StoredSample& s : file.samples) samples_W_.push_back(s.p_W);
  for (const StoredArm& arm : file.arms) instrument_.push_back(arm.role == "instrument");
}

PlanCollisions::~PlanCollisions() = default;

void PlanCollisions::SetState(const robot::RobotState& state, int work_sample) {
  TROCAR_THROW_UNLESS(work_sample < static_cast<int>(samples_W_.size()),
                      "plan collisions: target sample " << work_sample << " of "
                                                        << samples_W_.size());
  checker_->SetRobotState(state);
  checker_->ClearWorkSites();
  for (std::size_t a = 0; a < port_of_arm_.size(); ++a) {
    double allowance = allowance_[a];
    if (skin_ && instrument_[a] && tool_frame_[a].link >= 0 && !state.X_WL.empty()) {
      const Eigen::Vector3d tip_W =
          kinematics::FramePose(state, tool_frame_[a]).translation();
      allowance = std::max(allowance,
                           TrackAllowance(*skin_, depth_[a], X_PW_ * pivots_[a], incisions_P_[a],
                                          X_PW_ * tip_W, world_->options().port_radius));
    }
    checker_->SetPortPosition(port_of_arm_[a], pivots_[a], allowance);
    if (work_sample >= 0 && instrument_[a])
      checker_->SetWorkSite(port_of_arm_[a], samples_W_[work_sample], kWorkSiteRadius);
  }
}

std::vector<collision::Clearance> PlanCollisions::ArmsNearest(const robot::RobotState& state,
                                                              const std::vector<int>& arm_links) {
  SetState(state);
  std::vector<collision::Clearance> out;
  const auto& arms = world_->arms();
  for (int link : arm_links) {
    int arm = -1;
    for (int l = link; l >= 0 && arm < 0;) {
      for (std::size_t k = 0; k < arms.size(); ++k)
        if (arms[k].root_link == l) arm = static_cast<int>(k);
      const int j = robot_->link(l).parent_joint;
      l = j >= 0 ? robot_->joint(j).parent_link : -1;
    }
    collision::Clearance c;
    if (arm >= 0) {
      c = checker_->MinimumDistance(collision::kAllMovingPairs & ~collision::Bit(collision::PairClass::kSelf), arm);
      if (c.valid() && world_->bodies()[c.a].arm != arm) {  // the arm's body first
        std::swap(c.a, c.b);
        std::swap(c.p_W_a, c.p_W_b);
      }
    }
    out.push_back(c);
  }
  return out;
}

std::string PlanCollisions::PairName(const collision::Clearance& c) const {
  if (!c.valid()) return "";
  return world_->bodies()[c.a].name + " - " + world_->bodies()[c.b].name;
}

PoseCollisions PlanCollisions::Check(const robot::RobotState& state, double near_miss,
                                     int work_sample) {
  SetState(state, work_sample);
  PoseCollisions out;
  const auto& bodies = world_->bodies();
  auto add_link = [&](std::vector<int>* links, int body) {
    const int link = bodies[body].link;
    if (bodies[body].kind == collision::Body::Kind::kRobot && link >= 0 &&
        std::find(links->begin(), links->end(), link) == links->end())
      links->push_back(link);
  };
  const collision::CollisionReport report = checker_->Check();
  out.collision = report.collision;
  for (const auto& c : report.contacts) {
    out.pairs.push_back(bodies[c.a].name + " - " + bodies[c.b].name);
    add_link(&out.colliding_links, c.a);
    add_link(&out.colliding_links, c.b);
  }
  out.near_links = out.colliding_links;
  const std::vector<collision::Clearance> by_class = checker_->ClearanceByClass();
  out.clearance = std::numeric_limits<double>::infinity();
  for (const auto& c : by_class) {
    if (!c.valid()) continue;
    if (c.distance < out.clearance) {
      out.clearance = c.distance;
      out.clearance_pair = bodies[c.a].name + " - " + bodies[c.b].name;
    }
    if (c.distance < near_miss) {
      add_link(&out.near_links, c.a);
      add_link(&out.near_links, c.b);
    }
  }
  if (out.collision) out.clearance = 0.0;
  return out;
}

}  // namespace trocar::planners
