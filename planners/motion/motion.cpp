#include "motion/motion.hpp"

#include <ompl/base/PlannerData.h>
#include <ompl/base/ProblemDefinition.h>
#include <ompl/base/SpaceInformation.h>
#include <ompl/base/goals/GoalStates.h>
#include <ompl/base/spaces/RealVectorStateSpace.h>
#include <ompl/geometric/PathGeometric.h>
#include <ompl/geometric/PathSimplifier.h>
#include <ompl/geometric/planners/est/BiEST.h>
#include <ompl/geometric/planners/est/EST.h>
#include <ompl/geometric/planners/est/ProjEST.h>
#include <ompl/geometric/planners/fmt/BFMT.h>
#include <ompl/geometric/planners/fmt/FMT.h>
#include <ompl/geometric/planners/informedtrees/ABITstar.h>
#include <ompl/geometric/planners/informedtrees/AITstar.h>
#include <ompl/geometric/planners/informedtrees/BITstar.h>
#include <ompl/geometric/planners/kpiece/BKPIECE1.h>
#include <ompl/geometric/planners/kpiece/KPIECE1.h>
#include <ompl/geometric/planners/kpiece/LBKPIECE1.h>
#include <ompl/geometric/planners/pdst/PDST.h>
#include <ompl/geometric/planners/prm/LazyPRM.h>
#include <ompl/geometric/planners/prm/LazyPRMstar.h>
#include <ompl/geometric/planners/prm/PRM.h>
#include <ompl/geometric/planners/prm/PRMstar.h>
#include <ompl/geometric/planners/prm/SPARS.h>
#include <ompl/geometric/planners/prm/SPARStwo.h>
#include <ompl/geometric/planners/rlrt/BiRLRT.h>
#include <ompl/geometric/planners/rlrt/RLRT.h>
#include <ompl/geometric/planners/rrt/BiTRRT.h>
#include <ompl/geometric/planners/rrt/InformedRRTstar.h>
#include <ompl/geometric/planners/rrt/LBTRRT.h>
#include <ompl/geometric/planners/rrt/LazyRRT.h>
#include <ompl/geometric/planners/rrt/RRT.h>
#include <ompl/geometric/planners/rrt/RRTConnect.h>
#include <ompl/geometric/planners/rrt/RRTXstatic.h>
#include <ompl/geometric/planners/rrt/RRTsharp.h>
#include <ompl/geometric/planners/rrt/RRTstar.h>
#include <ompl/geometric/planners/rrt/TRRT.h>
#include <ompl/geometric/planners/sbl/SBL.h>
#include <ompl/geometric/planners/sst/SST.h>
#include <ompl/geometric/planners/stride/STRIDE.h>
#include <ompl/util/Console.h>
#include <ompl/util/RandomNumbers.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <map>
#include <mutex>
#include <random>
#include <sstream>

#include "collision/collision_world.hpp"
#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"

namespace trocar::planners {
namespace ob = ompl::base;
namespace og = ompl::geometric;

namespace {

// Prismatic joints count this many radians per metre in joint-space distances and steps: an
// instrument's 0.24 m insertion weighs like 2.4 rad of a revolute joint.
constexpr double kPrismaticWeight = 10.0;

using Allocator = std::function<ob::PlannerPtr(const ob::SpaceInformationPtr&)>;

template <class P>
Allocator Make() {
  return [](const ob::SpaceInformationPtr& si) { return std::make_shared<P>(si); };
}

// Lower-case name → (OMPL's name, allocator). Every geometric planner of OMPL 1.5.2 that plans
// from a start to goal states with a state validity checker alone (not QRRT, which needs a
// sequence of spaces; VFRRT, a vector field; TSRRT, a task space; Thunder and Lightning, an
// experience database; pRRT, pSBL and CForest, which run their own threads over one planner;
// LazyLBTRRT, which fails an assertion inside OMPL 1.5.2 on the bundled phantom).
const std::map<std::string, std::pair<std::string, Allocator>>& Registry() {
  static const std::map<std::string, std::pair<std::string, Allocator>> registry = {
      {"rrtconnect", {"RRTConnect", Make<og::RRTConnect>()}},
      {"rrt", {"RRT", Make<og::RRT>()}},
      {"rrtstar", {"RRTstar", Make<og::RRTstar>()}},
      {"informedrrtstar", {"InformedRRTstar", Make<og::InformedRRTstar>()}},
      // SORRTstar is not offered: Debian's OMPL 1.6 loops in OrderedInfSampler::sampleUniform
      // (rejection sampling of the informed set, never asking the termination condition) once a
      // path is found on the operative-world plans; seen as a test that never ended (issue #41).
      {"rrtsharp", {"RRTsharp", Make<og::RRTsharp>()}},
      {"rrtxstatic", {"RRTXstatic", Make<og::RRTXstatic>()}},
      {"lazyrrt", {"LazyRRT", Make<og::LazyRRT>()}},
      {"trrt", {"TRRT", Make<og::TRRT>()}},
      {"bitrrt", {"BiTRRT", Make<og::BiTRRT>()}},
      {"lbtrrt", {"LBTRRT", Make<og::LBTRRT>()}},
      {"prm", {"PRM", Make<og::PRM>()}},
      {"prmstar", {"PRMstar", Make<og::PRMstar>()}},
      {"lazyprm", {"LazyPRM", Make<og::LazyPRM>()}},
      {"lazyprmstar", {"LazyPRMstar", Make<og::LazyPRMstar>()}},
      {"spars", {"SPARS", Make<og::SPARS>()}},
      {"sparstwo", {"SPARStwo", Make<og::SPARStwo>()}},
      {"kpiece1", {"KPIECE1", Make<og::KPIECE1>()}},
      {"bkpiece1", {"BKPIECE1", Make<og::BKPIECE1>()}},
      {"lbkpiece1", {"LBKPIECE1", Make<og::LBKPIECE1>()}},
      {"est", {"EST", Make<og::EST>()}},
      {"biest", {"BiEST", Make<og::BiEST>()}},
      {"projest", {"ProjEST", Make<og::ProjEST>()}},
      {"sbl", {"SBL", Make<og::SBL>()}},
      {"stride", {"STRIDE", Make<og::STRIDE>()}},
      {"pdst", {"PDST", Make<og::PDST>()}},
      {"fmt", {"FMT", Make<og::FMT>()}},
      {"bfmt", {"BFMT", Make<og::BFMT>()}},
      {"bitstar", {"BITstar", Make<og::BITstar>()}},
      {"abitstar", {"ABITstar", Make<og::ABITstar>()}},
      {"aitstar", {"AITstar", Make<og::AITstar>()}},
      {"sst", {"SST", Make<og::SST>()}},
      {"rlrt", {"RLRT", Make<og::RLRT>()}},
      {"birlrt", {"BiRLRT", Make<og::BiRLRT>()}},
  };
  return registry;
}

std::string ValidNames() {
  std::string names;
  for (const auto& [name, entry] : Registry()) names += (names.empty() ? "" : ", ") + name;
  return names;
}

// OMPL's seed sequence is process-wide: held while a query makes its OMPL objects, and while a
// sampler is made mid-solve (its RNG draws a seed from the sequence even though SeededSampler
// then replaces it: unheld, that draw could fall between another thread's restart of the sequence
// and its simplifier's draw, and the simplified path would depend on the threads' timing; seen as
// a different path when the collision checks got faster). Recursive: OMPL may make a sampler
// inside a query's set-up.
std::recursive_mutex& OmplMutex() {
  static std::recursive_mutex mutex;
  return mutex;
}

// OMPL logs every solve at INFO level, and an ERROR each time the seed sequence is restarted
// (which is how each query gets its own seed): trocar reports outcomes itself.
void QuietOmpl() {
  static std::once_flag once;
  std::call_once(once, [] { ompl::msg::setLogLevel(ompl::msg::LOG_NONE); });
}

std::uint32_t QuerySeed(unsigned seed, int arm, int sample) {
  std::seed_seq seq{seed, static_cast<unsigned>(arm), static_cast<unsigned>(sample), 0x7a3du};
  std::uint32_t out[1];
  seq.generate(out, out + 1);
  return out[0] % 1000000000u + 1u;  // OMPL's seeds are positive
}

// Uniform samples from a generator of the query's own (OMPL's default sampler draws its seed
// from the process-wide sequence when the planner first asks for it, mid-solve).
class SeededSampler : public ob::RealVectorStateSampler {
 public:
  SeededSampler(const ob::StateSpace* space, std::uint32_t seed) : RealVectorStateSampler(space) {
    rng_.setLocalSeed(seed);
  }
};

class ArmSpace {
 public:
  ArmSpace(const robot::RobotModel& robot, const PlanArm& arm, const Eigen::VectorXd& q_start) {
    const int n = static_cast<int>(arm.q_indices.size());
    scale_.resize(n);
    lower_.resize(n);
    upper_.resize(n);
    for (int c = 0; c < n; ++c) {
      const int i = arm.q_indices[c];
      const robot::Joint& joint = robot.joint(robot.active_joints()[i]);
      scale_[c] = joint.type == robot::JointType::kPrismatic ? kPrismaticWeight : 1.0;
      double lo = joint.limits.lower, hi = joint.limits.upper;
      if (!std::isfinite(lo) || !std::isfinite(hi)) {  // a continuous joint: a turn around start
        lo = q_start[i] - M_PI;
        hi = q_start[i] + M_PI;
      }
      lower_[c] = lo;
      upper_[c] = hi;
    }
  }
  int size() const { return static_cast<int>(scale_.size()); }
  double scale(int c) const { return scale_[c]; }
  double lower(int c) const { return lower_[c]; }
  double upper(int c) const { return upper_[c]; }

 private:
  std::vector<double> scale_, lower_, upper_;
};

class ArmValidityChecker : public ob::StateValidityChecker {
 public:
  ArmValidityChecker(const ob::SpaceInformationPtr& si, MotionContext* context,
                     const PlanArm& arm, const ArmSpace& space, const Eigen::VectorXd& q_start)
      : ob::StateValidityChecker(si), context_(context), arm_(arm), space_(space), q_(q_start) {}
  bool isValid(const ob::State* state) const override {
    std::lock_guard<std::mutex> lock(mutex_);  // planners that check from a second thread
    Fill(state);
    return context_->Valid(q_);
  }
  double clearance(const ob::State* state) const override {
    std::lock_guard<std::mutex> lock(mutex_);
    Fill(state);
    return context_->Clearance(q_);
  }

 private:
  void Fill(const ob::State* state) const {
    const auto* s = state->as<ob::RealVectorStateSpace::StateType>();
    for (int c = 0; c < space_.size(); ++c) q_[arm_.q_indices[c]] = s->values[c] / space_.scale(c);
  }
  MotionContext* context_;
  const PlanArm& arm_;
  const ArmSpace& space_;
  mutable Eigen::VectorXd q_;
  mutable std::mutex mutex_;
};

// One query's OMPL objects: the arm's joint space (scaled), its validity checker (the context's
// collision checks), the start and the goal states, the planner and a path simplifier.
struct OmplQuery {
  ob::SpaceInformationPtr si;
  ob::ProblemDefinitionPtr pdef;
  ob::PlannerPtr planner;
  std::unique_ptr<og::PathSimplifier> simplifier;
};

// Made while the process-wide seed sequence restarts from the query's seed (OmplMutex), so that
// the same seed gives the same objects on any thread.
OmplQuery MakeOmplQuery(MotionContext* context, const PlanArm& arm, const ArmSpace& space,
                        const Eigen::VectorXd& q_start, const Eigen::VectorXd& start,
                        const std::vector<Eigen::VectorXd>& goals, const Allocator& make_planner,
                        const MotionOptions& options, std::uint32_t seed) {
  const int n = space.size();
  OmplQuery q;
  std::lock_guard<std::recursive_mutex> lock(OmplMutex());
  ompl::RNG::setSeed(seed);
  auto ompl_space = std::make_shared<ob::RealVectorStateSpace>(n);
  ob::RealVectorBounds bounds(n);
  for (int c = 0; c < n; ++c) {
    bounds.setLow(c, space.lower(c) * space.scale(c));
    bounds.setHigh(c, space.upper(c) * space.scale(c));
  }
  ompl_space->setBounds(bounds);
  auto sampler_count = std::make_shared<std::atomic<std::uint32_t>>(0);
  ompl_space->setStateSamplerAllocator([seed, sampler_count](const ob::StateSpace* s) {
    std::lock_guard<std::recursive_mutex> lock(OmplMutex());
    return std::make_shared<SeededSampler>(s, seed + 7919u * ++*sampler_count);
  });
  q.si = std::make_shared<ob::SpaceInformation>(ompl_space);
  q.si->setStateValidityChecker(
      std::make_shared<ArmValidityChecker>(q.si, context, arm, space, q_start));
  q.si->setStateValidityCheckingResolution(
      std::min(1.0, options.check_step / ompl_space->getMaximumExtent()));
  q.si->setup();
  q.pdef = std::make_shared<ob::ProblemDefinition>(q.si);
  auto to_state = [&](const Eigen::VectorXd& v, ob::State* s) {
    auto* rv = s->as<ob::RealVectorStateSpace::StateType>();
    for (int c = 0; c < n; ++c) rv->values[c] = v[c] * space.scale(c);
  };
  ob::ScopedState<> s(q.si);
  to_state(start, s.get());
  q.pdef->addStartState(s);
  auto goal_states = std::make_shared<ob::GoalStates>(q.si);
  for (const auto& g : goals) {
    ob::ScopedState<> gs(q.si);
    to_state(g, gs.get());
    goal_states->addState(gs);
  }
  q.pdef->setGoal(goal_states);
  q.planner = make_planner(q.si);
  q.planner->setProblemDefinition(q.pdef);
  q.planner->setup();
  q.simplifier = std::make_unique<og::PathSimplifier>(q.si);
  return q;
}

// A solved query's path into `out`: simplified (options.simplify), its lengths, segments and
// waypoints (the arm's joint values, unscaled).
void StorePath(og::PathGeometric* path, og::PathSimplifier* simplifier, const ArmSpace& space,
               const MotionOptions& options, TargetMotion* out) {
  const int n = space.size();
  out->raw_path_length = path->length();
  if (options.simplify) {
    // A fixed sequence of OMPL's steps, each bounded by the path's states, not by a clock: the
    // same path from the same seed on any machine (a timed simplify stopped by its limit is not),
    // and no B-spline smoothing (it multiplies the states, each checked along its motion: it took
    // most of a verification's time, measured in docs/decisions.md).
    const auto t1 = std::chrono::steady_clock::now();
    simplifier->reduceVertices(*path);
    simplifier->collapseCloseVertices(*path);
    for (int round = 0; round < 5 && simplifier->shortcutPath(*path); ++round) {
    }
    simplifier->reduceVertices(*path);
    out->simplification_time =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  }
  out->path_length = path->length();
  out->segments = static_cast<int>(path->getStateCount()) - 1;
  for (std::size_t k = 0; k < path->getStateCount(); ++k) {
    const auto* rv = path->getState(k)->as<ob::RealVectorStateSpace::StateType>();
    Eigen::VectorXd v(n);
    for (int c = 0; c < n; ++c) v[c] = rv->values[c] / space.scale(c);
    out->path.push_back(v);
  }
}

double WeightedStep(const ArmSpace& space, const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  double largest = 0.0;
  for (int c = 0; c < space.size(); ++c)
    largest = std::max(largest, std::abs(b[c] - a[c]) * space.scale(c));
  return largest;
}

}  // namespace

std::vector<std::string> MotionPlanners() {
  std::vector<std::string> names;
  for (const auto& [name, entry] : Registry()) names.push_back(name);
  return names;
}

std::string OmplPlannerName(const std::string& planner) {
  const auto it = Registry().find(planner);
  TROCAR_THROW_UNLESS(it != Registry().end(),
                      "unknown motion planner '" << planner << "' (valid: " << ValidNames() << ")");
  return it->second.first;
}

void ValidateMotionOptions(const MotionOptions& o) {
  TROCAR_OPTION_UNLESS(Registry().count(o.planner) > 0, "planner",
                       "unknown motion planner '" << o.planner << "' (valid: " << ValidNames()
                                                  << ")");
  TROCAR_OPTION_UNLESS(std::isfinite(o.time_limit) && o.time_limit > 0, "time_limit",
                       o.time_limit << " s, expected a positive number of seconds");
  TROCAR_OPTION_UNLESS(std::isfinite(o.check_step) && o.check_step > 0 && o.check_step < 1,
                       "check_step", o.check_step << ", expected (0, 1) rad");
  TROCAR_OPTION_UNLESS(
      std::isfinite(o.recheck_step) && o.recheck_step > 0 && o.recheck_step <= o.check_step,
      "recheck_step",
      o.recheck_step << ", expected positive and at most the check step " << o.check_step);
  TROCAR_OPTION_UNLESS(o.ik_restarts >= 1 && o.ik_restarts <= 1000, "ik_restarts",
                       o.ik_restarts << ", expected 1..1000");
  TROCAR_OPTION_UNLESS(o.goal_states >= 1 && o.goal_states <= 100, "goal_states",
                       o.goal_states << ", expected 1..100");
}

std::string ToString(MotionStatus status) {
  const auto names = MotionStatusNames();
  const int i = static_cast<int>(status);
  return i >= 0 && i < static_cast<int>(names.size()) ? names[i] : "Unknown status";
}

std::vector<std::string> MotionStatusNames() {
  std::vector<std::string> names;
  for (int i = 0; i < ob::PlannerStatus::TYPE_COUNT; ++i)
    names.push_back(ob::PlannerStatus(static_cast<ob::PlannerStatus::StatusType>(i)).asString());
  return names;
}

MotionProblem::MotionProblem(const PortPlacementProblem& problem, Placement placement,
                             Eigen::VectorXd q_start, Eigen::VectorXd joint_values)
    : problem_(problem),
      placement_(std::move(placement)),
      q_start_(std::move(q_start)),
      joint_values_(std::move(joint_values)) {
  const robot::RobotModel& robot = problem.robot();
  TROCAR_THROW_UNLESS(placement_.sites.size() == problem.arms().size(),
                      "motion: the placement has " << placement_.sites.size() << " ports for "
                                                   << problem.arms().size() << " arms");
  TROCAR_THROW_UNLESS(q_start_.size() == robot.num_positions(),
                      "motion: start q has " << q_start_.size() << " values, the robot "
                                             << robot.num_positions());
  TROCAR_THROW_UNLESS(joint_values_.size() == robot.num_dofs(),
                      "motion: start joint values have " << joint_values_.size()
                                                         << " values, the robot "
                                                         << robot.num_dofs());
}

MotionProblem::MotionProblem(const PortPlacementProblem& problem, const Placement& placement,
                             const Evaluation& evaluation)
    : MotionProblem(problem, placement, evaluation.q_nominal, evaluation.joint_values) {}

MotionContext::MotionContext(const MotionProblem& problem)
    : problem_(problem),
      state_(problem.problem().robot()),
      checker_(std::make_unique<collision::CollisionChecker>(problem.problem().world())) {
  QuietOmpl();
  state_.X_WB = problem.placement().X_WB();
  state_.joint_values = problem.joint_values();
}

MotionContext::~MotionContext() = default;

void MotionContext::SetPorts() {
  problem_.problem().SetPorts(problem_.placement(), state_, checker_.get(), has_work_ ? &work_W_ : nullptr);
}

int MotionContext::PairsToCheck(const Eigen::VectorXd& q) const {
  if (only_arm_ < 0) return -1;
  const Eigen::VectorXd& q_start = problem_.q_start();
  if (q.size() != q_start.size()) return -1;
  for (int i = 0; i < q.size(); ++i) {
    if (!in_query_arm_[static_cast<std::size_t>(i)] && q[i] != q_start[i]) return -1;
  }
  return only_arm_;
}

bool MotionContext::Valid(const Eigen::VectorXd& q, std::string* why) {
  ++checks_;
  const robot::RobotModel& robot = problem_.problem().robot();
  for (int i = 0; i < q.size(); ++i) {
    if (!std::isfinite(q[i])) {
      if (why) *why = "not a number in q";
      return false;
    }
  }
  const auto violations = kinematics::LimitViolations(robot, q);
  if (!violations.empty()) {
    if (why) *why = violations.front();
    return false;
  }
  const kinematics::ConfigurationResult fk = kinematics::ForwardKinematics(robot, q, &state_);
  if (!fk.ok()) {
    if (why) *why = "the closures do not solve: " + fk.message;
    return false;
  }
  checker_->SetRobotState(state_);
  SetPorts();
  const int pairs_of = PairsToCheck(q);
  if (!checker_->InCollision(collision::kAllMovingPairs, pairs_of)) return true;
  if (why) {
    const auto report = checker_->Check(collision::kAllMovingPairs, pairs_of);
    *why = report.contacts.empty()
               ? std::string("collision")
               : "collision: " + checker_->world().DescribePair(report.contacts.front().a,
                                                                report.contacts.front().b);
  }
  return false;
}

double MotionContext::Clearance(const Eigen::VectorXd& q) {
  const robot::RobotModel& robot = problem_.problem().robot();
  if (!kinematics::ForwardKinematics(robot, q, &state_).ok()) return 0.0;
  checker_->SetRobotState(state_);
  SetPorts();
  const collision::Clearance c = checker_->MinimumDistance();
  return c.valid() ? c.distance : std::numeric_limits<double>::infinity();
}

std::string MotionContext::Recheck(int arm_index, const std::vector<Eigen::VectorXd>& path,
                                   double step, int* states_checked, double* min_clearance,
                                   double* tip_path_length) {
  const PortPlacementProblem& problem = problem_.problem();
  const robot::RobotModel& robot = problem.robot();
  TROCAR_THROW_UNLESS(arm_index >= 0 && arm_index < static_cast<int>(problem.arms().size()),
                      "re-check: arm " << arm_index);
  const PlanArm& arm = problem.arms()[arm_index];
  const ArmSpace space(robot, arm, problem_.q_start());
  const robot::Frame& tool = robot.GetFrame(arm.tool_frame);
  int checked = 0;
  double clearance = std::numeric_limits<double>::infinity(), tip_length = 0.0;
  Eigen::Vector3d previous_tip = Eigen::Vector3d::Zero();
  Eigen::VectorXd q = problem_.q_start();
  // Every state: the first waypoint, then each segment cut so that no joint moves more than
  // `step` between two checked states.
  int total = path.empty() ? 0 : 1;
  for (std::size_t k = 1; k < path.size(); ++k)
    total += std::max(1, static_cast<int>(std::ceil(WeightedStep(space, path[k - 1], path[k]) / step)));
  std::string failure;
  auto check = [&](const Eigen::VectorXd& q_arm) {
    for (int c = 0; c < space.size(); ++c) q[arm.q_indices[c]] = q_arm[c];
    ++checked;
    std::string why;
    if (!Valid(q, &why)) {
      std::ostringstream s;
      s << "state " << checked << " of " << total << ": " << why;
      failure = s.str();
      return false;
    }
    const Eigen::Vector3d tip = kinematics::FramePose(state_, tool).translation();
    if (checked > 1) tip_length += (tip - previous_tip).norm();
    previous_tip = tip;
    if (min_clearance) {  // only a state nearer than the path's minimum so far can lower it
      // The first state over every pair; then those that can have changed (PairsToCheck).
      const collision::Clearance c = checker_->MinimumDistance(
          collision::kAllMovingPairs, checked == 1 ? -1 : PairsToCheck(q), clearance);
      if (c.valid()) clearance = std::min(clearance, c.distance);
    }
    return true;
  };
  for (std::size_t k = 0; k < path.size() && failure.empty(); ++k) {
    TROCAR_THROW_UNLESS(path[k].size() == space.size(),
                        "re-check: waypoint " << k << " has " << path[k].size() << " values, arm "
                                              << arm.name << " " << space.size());
    if (k == 0) {
      check(path[0]);
      continue;
    }
    const int n = std::max(
        1, static_cast<int>(std::ceil(WeightedStep(space, path[k - 1], path[k]) / step)));
    for (int i = 1; i <= n && failure.empty(); ++i) {
      const double t = static_cast<double>(i) / n;
      check(Eigen::VectorXd((1.0 - t) * path[k - 1] + t * path[k]));
    }
  }
  if (states_checked) *states_checked = checked;
  if (min_clearance) *min_clearance = clearance;
  if (tip_path_length) *tip_path_length = tip_length;
  return failure;
}

TargetMotion MotionContext::Plan(int arm_index, int sample_index, const MotionOptions& options) {
  using Clock = std::chrono::steady_clock;
  const PortPlacementProblem& problem = problem_.problem();
  const robot::RobotModel& robot = problem.robot();
  TROCAR_THROW_UNLESS(arm_index >= 0 && arm_index < static_cast<int>(problem.arms().size()),
                      "motion: arm " << arm_index << " of " << problem.arms().size());
  TROCAR_THROW_UNLESS(
      sample_index >= 0 && sample_index < static_cast<int>(problem.samples().size()),
      "motion: target sample " << sample_index << " of " << problem.samples().size());
  const PlanArm& arm = problem.arms()[arm_index];
  const auto& entry = Registry().at(options.planner);
  TargetMotion out;
  out.arm = arm_index;
  out.sample = sample_index;
  const ArmSpace space(robot, arm, problem_.q_start());
  const int n = space.size();
  auto arm_q = [&](const Eigen::VectorXd& q) {
    Eigen::VectorXd v(n);
    for (int c = 0; c < n; ++c) v[c] = q[arm.q_indices[c]];
    return v;
  };
  const std::uint32_t seed = QuerySeed(options.seed, arm_index, sample_index);
  // The instruments work on this sample: their wrist and jaws may touch the organ there, for the
  // whole query (the start, the goals, the path and its re-check).
  has_work_ = true;
  work_W_ = problem.samples()[sample_index].p_W;
  struct ClearWork {
    bool* flag;
    int* only_arm;
    ~ClearWork() {
      *flag = false;
      *only_arm = -1;
    }
  } clear_work{&has_work_, &only_arm_};

  // The start: the arm at its nominal pose.
  const Eigen::VectorXd start = arm_q(problem_.q_start());
  {
    std::string why;
    if (!Valid(problem_.q_start(), &why)) {
      out.status = MotionStatus::kInvalidStart;
      out.outcome = "invalid start";
      out.reason = "the start pose is not valid: " + why;
      return out;
    }
  }
  // Valid over every pair at the start: from here on, a state that moves this arm alone needs
  // only its own pairs checked (PairsToCheck).
  only_arm_ = problem.world_arm(arm_index);
  in_query_arm_.assign(static_cast<std::size_t>(problem_.q_start().size()), 0);
  for (const int i : arm.q_indices) in_query_arm_[static_cast<std::size_t>(i)] = 1;
  // Goals: inverse kinematics from the nominal pose and the problem's other wrist poses (the
  // attempts the plan's claimed reach made: PortPlacementProblem::ReachSeed), then from seeded
  // random poses of the arm.
  std::vector<Eigen::VectorXd> goals;
  std::string goal_failure;
  Eigen::VectorXd goal_failure_q;  // the pose goal_failure describes
  {
    std::mt19937 rng(seed);
    robot::RobotState ik_state = state_;
    const int seeded = problem.ReachRestarts(arm_index);  // before the random ones
    for (int r = 0; r < 1 + seeded + std::max(0, options.ik_restarts - 1) &&
                    static_cast<int>(goals.size()) < options.goal_states;
         ++r) {
      ik_state.X_WB = problem_.placement().X_WB();
      ik_state.joint_values = problem_.joint_values();
      ik_state.q = problem_.q_start();
      if (r > seeded) {
        for (int c = 0; c < n; ++c) {
          ik_state.q[arm.q_indices[c]] =
              std::uniform_real_distribution<double>(space.lower(c), space.upper(c))(rng);
        }
      } else {
        problem.ReachSeed(arm_index, r, &ik_state);
      }
      if (!kinematics::ForwardKinematics(robot, ik_state.q, &ik_state).ok()) continue;
      const std::string failure = problem.SolveReach(arm_index, problem_.placement(),
                                                     problem.samples()[sample_index], &ik_state);
      if (!failure.empty()) {
        if (goal_failure.empty()) {
          goal_failure = failure;
          goal_failure_q = arm_q(ik_state.q);
        }
        continue;
      }
      std::string why;
      if (!Valid(ik_state.q, &why)) {
        if (goal_failure.empty() || goal_failure.rfind("no inverse", 0) == 0) {
          goal_failure = "the inverse-kinematics solution is not valid: " + why;
          goal_failure_q = arm_q(ik_state.q);
        }
        continue;
      }
      const Eigen::VectorXd goal = arm_q(ik_state.q);
      bool distinct = true;
      for (const auto& g : goals) distinct = distinct && WeightedStep(space, g, goal) > 0.05;
      if (distinct) goals.push_back(goal);
    }
  }
  if (goals.empty()) {
    out.status = MotionStatus::kInvalidGoal;
    out.outcome = "unreachable";
    out.reason = goal_failure.empty() ? "no inverse-kinematics solution" : goal_failure;
    out.failure_q = goal_failure_q;
    return out;
  }

  // OMPL's objects, made while the process-wide seed sequence restarts from this query's seed.
  const OmplQuery query = MakeOmplQuery(this, arm, space, problem_.q_start(), start, goals,
                                        entry.second, options, seed);
  const ob::PlannerPtr& planner = query.planner;
  const ob::ProblemDefinitionPtr& pdef = query.pdef;
  const ob::SpaceInformationPtr& si = query.si;
  og::PathSimplifier* simplifier = query.simplifier.get();

  const auto t0 = Clock::now();
  const ob::PlannerStatus status = planner->solve(ob::timedPlannerTerminationCondition(options.time_limit));
  out.planning_time = std::chrono::duration<double>(Clock::now() - t0).count();
  out.status = static_cast<MotionStatus>(static_cast<ob::PlannerStatus::StatusType>(status));
  {
    ob::PlannerData data(si);
    planner->getPlannerData(data);
    out.graph_states = data.numVertices();
    out.graph_motions = data.numEdges();
  }
  if (out.status != MotionStatus::kExactSolution) {
    out.outcome = out.status == MotionStatus::kTimeout ||
                          out.status == MotionStatus::kApproximateSolution
                      ? "timeout"
                      : "failed";
    std::ostringstream why;
    why << "no collision-free motion found in " << options.time_limit << " s ("
        << ToString(out.status) << ")";
    out.reason = why.str();
    out.failure_q = goals.front();
    return out;
  }
  StorePath(pdef->getSolutionPath()->as<og::PathGeometric>(), simplifier, space, options, &out);
  const std::string failure = Recheck(arm_index, out.path, options.recheck_step,
                                      &out.rechecked_states, &out.min_clearance,
                                      &out.tip_path_length);
  out.correct = failure.empty();
  out.solved = out.correct;
  out.outcome = out.solved ? "solved" : "rejected";
  if (!out.correct) out.reason = "the re-check rejected the path: " + failure;
  return out;
}

}  // namespace trocar::planners
