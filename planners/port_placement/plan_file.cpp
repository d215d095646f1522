#include "port_placement/plan_file.hpp"

#include <algorithm>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/json_util.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "port_placement/plan_io.hpp"

namespace trocar::planners {
namespace {

/// Physical ranges of a plan's numbers (issue #44 item 1): a room is metres across (m), and a
/// joint turns a few times at most or slides a few metres (rad or m).
constexpr double kMaxRoomCoordinate = 100.0;
constexpr double kMaxJointValue = 1000.0;
/// Sizes a plan can hold: an arm's joints, a motion's waypoints.
constexpr std::size_t kMaxArmJoints = 64, kMaxWaypoints = 100000;

using nlohmann::json;

/// A JSON value with its path in the document, for messages.
struct Field {
  const std::string& file;
  const json& j;
  std::string path;

  [[noreturn]] void Fail(const std::string& expected) const {
    TROCAR_THROW(file << ": " << (path.empty() ? "the document" : path) << ": expected "
                      << expected << (j.is_null() ? "" : ", found " + j.dump().substr(0, 60)));
  }
  bool Has(const std::string& key) const { return j.is_object() && j.contains(key); }
  Field operator[](const std::string& key) const {
    if (!j.is_object()) Fail("an object");
    if (!j.contains(key)) {
      TROCAR_THROW(file << ": " << (path.empty() ? "" : path + ".") << key << ": missing");
    }
    return {file, j.at(key), path.empty() ? key : path + "." + key};
  }
  Field operator[](std::size_t i) const {
    return {file, j.at(i), path + "[" + std::to_string(i) + "]"};
  }
  std::size_t Size() const {
    if (!j.is_array()) Fail("an array");
    return j.size();
  }
  double Number() const {
    if (!j.is_number()) Fail("a number");
    const double v = j.get<double>();
    if (!std::isfinite(v)) Fail("a finite number");
    return v;
  }
  int Integer() const {
    if (!j.is_number_integer()) Fail("an integer");
    return JsonInt(j, file, path.empty() ? "the document" : path);
  }
  bool Bool() const {
    if (!j.is_boolean()) Fail("true or false");
    return j.get<bool>();
  }
  std::string String() const {
    if (!j.is_string()) Fail("a string");
    return j.get<std::string>();
  }
  Eigen::Vector3d Vec3() const {
    if (Size() != 3) Fail("3 numbers");
    return {(*this)[0].Number(), (*this)[1].Number(), (*this)[2].Number()};
  }
  /// A point of the operating room (m): within kMaxRoomCoordinate of its origin.
  Eigen::Vector3d Position() const {
    const Eigen::Vector3d p = Vec3();
    if (p.cwiseAbs().maxCoeff() > kMaxRoomCoordinate) Fail("a point within 100 m of the room's origin");
    return p;
  }
  /// A unit direction (within 1e-6).
  Eigen::Vector3d Direction() const {
    const Eigen::Vector3d d = Vec3();
    if (std::abs(d.norm() - 1.0) > 1e-6) Fail("a unit vector");
    return d;
  }
  Eigen::Isometry3d Pose() const {
    if (Size() != 4) Fail("a 4x4 matrix");
    Eigen::Matrix4d m;
    for (int r = 0; r < 4; ++r) {
      const Field row = (*this)[r];
      if (row.Size() != 4) row.Fail("4 numbers");
      for (int c = 0; c < 4; ++c) m(r, c) = row[c].Number();
    }
    const Eigen::Matrix3d R = m.topLeftCorner<3, 3>();
    if ((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-6 || R.determinant() < 0 ||
        m.row(3).head<3>().norm() > 1e-9 || std::abs(m(3, 3) - 1) > 1e-9) {
      Fail("a rigid transform (rotation and translation)");
    }
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.linear() = R;
    X.translation() = m.topRightCorner<3, 1>();
    return X;
  }
  std::vector<std::string> Strings() const {
    std::vector<std::string> out;
    for (std::size_t i = 0; i < Size(); ++i) out.push_back((*this)[i].String());
    return out;
  }
  std::vector<std::pair<std::string, double>> NamedNumbers() const {
    if (!j.is_object()) Fail("an object of joint names and values");
    std::vector<std::pair<std::string, double>> out;
    for (const auto& [name, value] : j.items()) {
      const double v = (*this)[name].Number();
      // Joint values in rad or m: 1e300 is no pose (a limit check downstream would still pass
      // it to sin and cos first).
      if (std::abs(v) > kMaxJointValue) (*this)[name].Fail("a joint value within 1000 (rad or m)");
      out.emplace_back(name, v);
    }
    return out;
  }
};

// The cart's pose: X_WB, checked against the x, y and yaw stored beside it (one pose, not two
// sources of truth: `check --plan` and `verify` once read the one, `view` and `report` the other).
Eigen::Isometry3d CartPose(const Field& cart) {
  const Eigen::Isometry3d X_WB = cart["X_WB"].Pose();
  const double x = cart["x"].Number(), y = cart["y"].Number();
  const double yaw = cart["yaw_deg"].Number() * M_PI / 180.0;
  Eigen::Isometry3d expected = Eigen::Isometry3d::Identity();
  expected.linear() = Eigen::AngleAxisd(yaw, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  expected.translation() = Eigen::Vector3d(x, y, 0.0);
  const double moved = (X_WB.translation() - expected.translation()).norm();
  const double turned = Eigen::AngleAxisd(X_WB.linear().transpose() * expected.linear()).angle();
  if (moved > 1e-6 || turned > 1e-6) {
    std::ostringstream m;
    m << "X_WB to agree with x, y and yaw_deg (the cart on the floor at (" << x << ", " << y
      << ") m, turned " << yaw * 180.0 / M_PI << " deg); it is " << moved * 1e3 << " mm and "
      << turned * 180.0 / M_PI << " deg from that";
    cart.Fail(m.str());
  }
  return X_WB;
}

StoredPlan ReadPlan(const Field& p, int rank_from = 1) {
  StoredPlan plan;
  plan.rank = p["rank"].Integer();
  if (plan.rank < rank_from) p["rank"].Fail("a rank from " + std::to_string(rank_from));
  plan.status = p["status"].String();
  plan.score = p["score"].Number();
  plan.rank_score = p["rank_score"].Number();
  if (p.Has("message")) plan.message = p["message"].String();
  plan.X_WB = CartPose(p["cart"]);
  plan.setup_joints = p["setup_joints"].NamedNumbers();
  plan.q_nominal = p["q_nominal"].NamedNumbers();
  const Field ports = p["ports"];
  for (std::size_t i = 0; i < ports.Size(); ++i) {
    StoredPort port;
    port.arm = ports[i]["arm"].String();
    port.candidate = ports[i]["candidate"].String();
    port.p_W = ports[i]["p_W"].Position();
    port.rcm_W = ports[i]["rcm_W"].Position();
    if (ports[i].Has("anatomy")) port.anatomy = ports[i]["anatomy"].String();
    plan.ports.push_back(port);
  }
  if (p.Has("views")) {
    const Field views = p["views"];
    for (std::size_t i = 0; i < views.Size(); ++i) {
      StoredView view;
      view.arm = views[i]["arm"].String();
      view.frame = views[i]["frame"].String();
      view.axis_F = views[i]["axis_F"].Vec3();
      if (std::abs(view.axis_F.norm() - 1) > 1e-3) views[i]["axis_F"].Fail("a unit vector");
      plan.views.push_back(view);
    }
  }
  const Field terms = p["terms"];
  for (std::size_t i = 0; i < terms.Size(); ++i) {
    StoredTerm t;
    t.name = terms[i]["name"].String();
    t.value = terms[i]["value"].Number();
    t.score = terms[i]["score"].Number();
    if (terms[i].Has("unit")) t.unit = terms[i]["unit"].String();
    if (terms[i].Has("weight")) t.weight = terms[i]["weight"].Number();
    plan.terms.push_back(t);
  }
  if (p.Has("verification")) {
    const Field v = p["verification"];
    plan.verified = true;
    plan.verified_coverage = v["verified_coverage"].Number();
    plan.claimed_coverage = v["claimed_coverage"].Number();
    plan.served_fraction = v["served_fraction"].Number();
    plan.verified_suitable = v["suitable"].Bool();
    plan.verification_reasons = v["reasons"].Strings();
    if (v.Has("served")) {
      const Field served = v["served"];
      for (std::size_t i = 0; i < served.Size(); ++i) plan.verified_served.push_back(served[i].Bool());
    }
    const Field motions = v["motions"];
    for (std::size_t i = 0; i < motions.Size(); ++i) {
      const Field m = motions[i];
      StoredMotion motion;
      motion.arm = m["arm"].String();
      motion.sample = m["sample"].Integer();
      motion.outcome = m["outcome"].String();
      if (m.Has("reason")) motion.reason = m["reason"].String();
      motion.solved = m["solved"].Bool();
      if (m.Has("min_clearance_m")) motion.min_clearance = m["min_clearance_m"].Number();
      if (m.Has("waypoints")) {
        motion.joints = m["joints"].Strings();
        if (motion.joints.size() > kMaxArmJoints) m["joints"].Fail("at most 64 joints of one arm");
        const Field w = m["waypoints"];
        // A simplified path has tens of waypoints; the re-check steps it at a fine step.
        if (w.Size() > kMaxWaypoints) w.Fail("at most 100000 waypoints");
        for (std::size_t k = 0; k < w.Size(); ++k) {
          if (w[k].Size() != motion.joints.size()) {
            w[k].Fail(std::to_string(motion.joints.size()) + " joint values");
          }
          Eigen::VectorXd q(motion.joints.size());
          for (std::size_t d = 0; d < motion.joints.size(); ++d) q[d] = w[k][d].Number();
          motion.waypoints.push_back(q);
        }
      }
      plan.motions.push_back(std::move(motion));
    }
  }
  if (p.Has("signoffs")) {
    const Field list = p["signoffs"];
    for (std::size_t i = 0; i < list.Size(); ++i) {
      SignOff s;
      s.decision = list[i]["decision"].String();
      s.surgeon = list[i]["surgeon"].String();
      s.note = list[i]["note"].String();
      s.time = list[i]["time"].String();
      if (list[i].Has("session")) {
        s.session = list[i]["session"].String();
        s.session_hash = list[i]["session_hash"].String();
      }
      if (list[i].Has("override")) {
        s.override_reason = list[i]["override"].String();
        const Field o = list[i]["overridden"];
        for (std::size_t k = 0; k < o.Size(); ++k) s.overridden.push_back(o[k].String());
      }
      plan.signoffs.push_back(s);
    }
  }
  return plan;
}

std::string UtcNow() {
  const std::time_t now = std::time(nullptr);
  std::tm tm{};
  gmtime_r(&now, &tm);
  char buffer[32];
  std::strftime(buffer, sizeof(buffer), "%Y-%m-%dT%H:%M:%SZ", &tm);
  return buffer;
}

}  // namespace

PlanFile ReadPlanFile(const std::string& path) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": no such plan file");
  json doc;
  try {
    doc = ReadJsonFile(path, "a plan");
  } catch (const json::exception& e) {
    TROCAR_THROW(path << ": not a plan (JSON: " << e.what() << ")");
  }
  const Field root{path, doc, ""};
  TROCAR_THROW_UNLESS(doc.is_object() && doc.contains("format") && doc["format"].is_string() &&
                          doc["format"].get<std::string>() == "trocar-plan",
                      path << ": not a trocar plan (field 'format' is not \"trocar-plan\")");
  TROCAR_THROW_UNLESS(root["version"].Integer() == kPlanFormatVersion,
                      path << ": plan format version " << doc.at("version")
                           << ", this trocar reads version " << kPlanFormatVersion);
  PlanFile file;
  file.path = path;
  const std::string plan_dir = ParentDirectory(path);
  // Plans name their inputs by absolute paths (since stop 61); a relative one (an older plan, or
  // one a user edited) from the working directory, else from the plan's folder.
  auto resolve = [&](const std::string& p) {
    return std::filesystem::exists(p) ? p : JoinPath(plan_dir, p);
  };
  const Field inputs = root["inputs"];
  file.case_dir = resolve(inputs["case"].String());
  file.robot_file = resolve(inputs["robot"].String());
  file.case_hash = inputs["case_hash"].String();
  file.robot_hash = inputs["robot_hash"].String();
  file.model_hash = inputs["patient_model_hash"].String();
  file.patient_name = root["patient"]["name"].String();
  file.X_WP = root["patient"]["X_WP"].Pose();
  const Field arms = root["robot"]["arms"];
  for (std::size_t i = 0; i < arms.Size(); ++i) {
    StoredArm arm;
    arm.name = arms[i]["name"].String();
    arm.role = arms[i]["role"].String();
    arm.tool_frame = arms[i]["tool_frame"].String();
    arm.rcm_frame = arms[i]["rcm_frame"].String();
    arm.shaft_link = arms[i]["shaft_link"].String();
    arm.joints = arms[i]["joints"].Strings();
    file.arms.push_back(arm);
  }
  const Field verdict = root["verdict"];
  file.suitable = verdict["suitable"].Bool();
  file.summary = verdict["summary"].String();
  file.reasons = verdict["reasons"].Strings();
  if (verdict.Has("verified")) {
    const Field v = verdict["verified"];
    file.has_verified_verdict = true;
    file.verified_suitable = v["suitable"].Bool();
    file.verified_summary = v["summary"].String();
    file.verified_reasons = v["reasons"].Strings();
  }
  const Field samples = root["target_samples"];
  for (std::size_t i = 0; i < samples.Size(); ++i) {
    StoredSample s;
    s.index = samples[i]["index"].Integer();
    s.target = samples[i]["target"].String();
    s.p_W = samples[i]["p_W"].Position();
    s.n_W = samples[i]["n_W"].Direction();
    file.samples.push_back(s);
  }
  const Field plans = root["plans"];
  if (plans.Size() == 0) plans.Fail("at least one plan");
  for (std::size_t i = 0; i < plans.Size(); ++i) {
    file.plans.push_back(ReadPlan(plans[i]));
    const StoredPlan& plan = file.plans.back();
    // One motion per (arm, sample) at most.
    TROCAR_THROW_UNLESS(plan.motions.size() <= file.arms.size() * file.samples.size(),
                        path << ": plans[" << i << "].verification.motions: "
                             << plan.motions.size() << " motions, more than one per arm ("
                             << file.arms.size() << ") and target sample (" << file.samples.size()
                             << ")");
    for (const StoredMotion& m : plan.motions) {
      TROCAR_THROW_UNLESS(m.sample >= 0 && m.sample < static_cast<int>(file.samples.size()),
                          path << ": plans[" << i << "].verification: a motion names sample "
                               << m.sample << ", the plan has " << file.samples.size());
    }
    TROCAR_THROW_UNLESS(plan.ports.size() == file.arms.size(),
                        path << ": plans[" << i << "].ports: " << plan.ports.size()
                             << " ports for " << file.arms.size() << " arms");
  }
  if (root.Has("baselines")) {
    const Field list = root["baselines"];
    for (std::size_t i = 0; i < list.Size(); ++i) {
      const Field b = list[i];
      StoredBaseline base;
      base.kind = b["kind"].String();
      base.name = b["name"].String();
      base.placed = b["placed"].Bool();
      if (!base.placed) {
        base.why_not = b["why_not"].String();
      } else {
        base.where = b["where"].Strings();
        base.plan = ReadPlan(b["plan"], /*rank_from=*/0);
        TROCAR_THROW_UNLESS(base.plan.ports.size() == file.arms.size(),
                            path << ": baselines[" << i << "].plan.ports: " << base.plan.ports.size()
                                 << " ports for " << file.arms.size() << " arms");
        base.suitable = b["verdict"]["suitable"].Bool();
        base.summary = b["verdict"]["summary"].String();
        base.reasons = b["verdict"]["reasons"].Strings();
      }
      file.baselines.push_back(std::move(base));
    }
  }
  // Per-sample lists as long as the samples.
  for (std::size_t i = 0; i < file.plans.size(); ++i) {
    const auto& served = file.plans[i].verified_served;
    TROCAR_THROW_UNLESS(served.empty() || served.size() == file.samples.size(),
                        path << ": plans[" << i << "].verification.served: " << served.size()
                             << " entries for " << file.samples.size() << " target samples");
  }
  return file;
}

std::string RobotFileMismatch(const PlanFile& file) {
  if (!IsRegularFile(file.robot_file)) return "its robot " + file.robot_file + " does not exist";
  if (HashFile(file.robot_file) != file.robot_hash)
    return "robot file " + file.robot_file + " changed since the plan was made (hash differs)";
  return "";
}

std::string PatientModelMismatch(const PlanFile& file, const patient::PatientModel& patient,
                                 const std::string& case_dir) {
  if (HashPatientModel(patient) == file.model_hash) return "";
  return "was made for another patient model than " + case_dir + "'s (hash differs)";
}

std::vector<std::string> ApprovalBlockers(const PlanFile& file, std::size_t index) {
  TROCAR_THROW_UNLESS(index < file.plans.size(), file.path << ": plan " << index + 1
                                                           << ": the file holds "
                                                           << file.plans.size() << " plans");
  const StoredPlan& plan = file.plans[index];
  std::vector<std::string> out;
  if (plan.status != "placed") {
    out.push_back("its nominal pose is " + plan.status +
                  (plan.status == "in collision" ? " (the arms cannot stand there)" : ""));
  }
  if (!plan.verified) {
    out.push_back("it was not verified by motions (planned without verification: verify the plan file first)");
  } else if (!plan.verified_suitable) {
    std::ostringstream why;
    why << "not suitable by its verified motions: " << std::lround(100 * plan.verified_coverage)
        << " % of the instrument motions verified, " << std::lround(100 * plan.served_fraction)
        << " % of the target samples served";
    for (std::size_t k = 0; k < std::min<std::size_t>(2, plan.verification_reasons.size()); ++k)
      why << "; " << plan.verification_reasons[k];
    out.push_back(why.str());
  }
  return out;
}

std::string PlanDecisionStatus(const PlanFile& file, std::size_t index) {
  TROCAR_THROW_UNLESS(index < file.plans.size(), file.path << ": plan " << index + 1
                                                           << ": the file holds "
                                                           << file.plans.size() << " plans");
  const auto& mine = file.plans[index].signoffs;
  if (mine.empty()) return "proposed";
  if (mine.back().decision != "approved") return mine.back().decision;
  // Superseded when another plan's standing approval is later than this one's (ISO 8601 UTC
  // times order as text; a tie keeps both approved).
  for (std::size_t k = 0; k < file.plans.size(); ++k) {
    const auto& other = file.plans[k].signoffs;
    if (k == index || other.empty() || other.back().decision != "approved") continue;
    if (other.back().time > mine.back().time) return "superseded";
  }
  return "approved";
}

SignOff SignOffPlan(const std::string& path, std::size_t index, SignOff signoff) {
  TROCAR_THROW_UNLESS(signoff.decision == "approved" || signoff.decision == "rejected",
                      path << ": sign-off decision '" << signoff.decision
                           << "': expected approved or rejected");
  TROCAR_THROW_UNLESS(!signoff.surgeon.empty(), path << ": a sign-off names its surgeon");
  TROCAR_THROW_UNLESS(signoff.note.size() <= 10000,
                      path << ": sign-off note of " << signoff.note.size()
                           << " characters: at most 10,000");
  // The whole file is read and checked first: a sign-off is only added to a plan this trocar reads.
  const PlanFile file = ReadPlanFile(path);
  TROCAR_THROW_UNLESS(index < file.plans.size(), path << ": plan " << index + 1 << ": the file holds "
                                                      << file.plans.size() << " plans");
  // An approval is a decision that the plan can be operated on: one that fails is refused unless
  // the surgeon overrides, with a reason, recorded beside the failures overridden.
  const std::vector<std::string> blockers = ApprovalBlockers(file, index);
  TROCAR_THROW_UNLESS(signoff.override_reason.size() <= 10000,
                      path << ": override reason of " << signoff.override_reason.size()
                           << " characters: at most 10,000");
  if (signoff.decision == "approved" && !blockers.empty()) {
    if (signoff.override_reason.empty()) {
      std::ostringstream m;
      m << path << ": plan " << index + 1 << " cannot be approved: ";
      for (std::size_t k = 0; k < blockers.size(); ++k) m << (k ? "; and " : "") << blockers[k];
      m << ". Approve it anyway only with an override reason, which is recorded with the failures "
           "it overrides";
      throw OptionError("override_reason", m.str());
    }
    signoff.overridden = blockers;
  } else {
    TROCAR_THROW_UNLESS(signoff.override_reason.empty(),
                        path << ": plan " << index + 1 << ": an override is given but "
                             << (signoff.decision == "approved"
                                     ? "nothing blocks its approval"
                                     : "a rejection needs none")
                             << "; leave it out");
    signoff.overridden.clear();
  }
  if (!signoff.session.empty()) {
    TROCAR_THROW_UNLESS(IsRegularFile(signoff.session),
                        path << ": sign-off session " << signoff.session << " does not exist");
    signoff.session_hash = HashFile(signoff.session);
  }
  signoff.time = UtcNow();
  json doc = ReadJsonFile(path, "a plan");
  json entry = {{"decision", signoff.decision}, {"surgeon", signoff.surgeon},
                {"note", signoff.note}, {"time", signoff.time}};
  if (!signoff.session.empty()) {
    entry["session"] = signoff.session;
    entry["session_hash"] = signoff.session_hash;
  }
  if (!signoff.override_reason.empty()) {
    entry["override"] = signoff.override_reason;
    entry["overridden"] = signoff.overridden;
  }
  json& plan = doc.at("plans").at(index);
  if (!plan.contains("signoffs")) plan["signoffs"] = json::array();
  plan["signoffs"].push_back(entry);
  WriteFileAtomically(path, doc.dump(1) + "\n");
  return signoff;
}

robot::RobotState NominalState(const robot::RobotModel& robot, const StoredPlan& plan,
                               const std::string& where) {
  robot::RobotState state(robot);
  state.X_WB = plan.X_WB;
  for (const auto& [name, value] : plan.setup_joints) {
    try {
      kinematics::SetHeldJoint(robot, name, value, &state);
    } catch (const Error& e) {
      TROCAR_THROW(where << ": setup joint '" << name << "': " << e.what());
    }
  }
  for (const auto& [name, value] : plan.q_nominal) {
    const int j = robot.FindJoint(name);
    TROCAR_THROW_UNLESS(j >= 0 && robot.joint(j).q_index >= 0,
                        where << ": q_nominal names '" << name << "', not an active joint of "
                              << robot.name());
    state.q[robot.joint(j).q_index] = value;
  }
  const auto fk = kinematics::ForwardKinematics(robot, state.q, &state);
  TROCAR_THROW_UNLESS(fk.ok(), where << ": nominal pose: " << fk.message);
  return state;
}

void SetWaypoint(const robot::RobotModel& robot, const StoredMotion& motion, std::size_t k,
                 robot::RobotState* state) {
  TROCAR_THROW_UNLESS(k < motion.waypoints.size(),
                      "motion of " << motion.arm << " to sample " << motion.sample << " has "
                                   << motion.waypoints.size() << " waypoints, not " << k + 1);
  Eigen::VectorXd q = state->q;
  for (std::size_t d = 0; d < motion.joints.size(); ++d) {
    const int j = robot.FindJoint(motion.joints[d]);
    TROCAR_THROW_UNLESS(j >= 0 && robot.joint(j).q_index >= 0,
                        "motion of " << motion.arm << ": '" << motion.joints[d]
                                     << "' is not an active joint of " << robot.name());
    q[robot.joint(j).q_index] = motion.waypoints[k][d];
  }
  const auto fk = kinematics::ForwardKinematics(robot, q, state);
  TROCAR_THROW_UNLESS(fk.ok(), "motion of " << motion.arm << " to sample " << motion.sample
                                          << ", waypoint " << k << ": " << fk.message);
}

}  // namespace trocar::planners
