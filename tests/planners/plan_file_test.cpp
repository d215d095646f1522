// The plan file's one owner (issue #45 item 1): a plan written, read back through the typed
// reader and written again keeps its bytes, every documented part included (verification,
// baselines placed and not, sign-offs, selection criteria with one not measured); a field nothing
// in trocar interprets, and one it does not know, still survive a rewrite; verify's problem is
// rebuilt from the file as it was scored.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <limits>
#include <memory>
#include <set>
#include <string>

#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "motion/verify.hpp"
#include "plan/plan_file.hpp"
#include "plan/signoff.hpp"
#include "planners/bundled.hpp"
#include "port_placement/optimizer.hpp"
#include "port_placement/plan_io.hpp"
#include "test_util.hpp"

namespace trocar::planners {
namespace {

using nlohmann::json;
using test_bundled::Cart;
using test_bundled::Phantom;

struct Written {
  std::unique_ptr<PortPlacementProblem> problem;
  PortPlacementOptions options;
  std::string path;  // the plan as trocar plan writes it
  std::string text;  // its bytes
};

// A plan of an instrument and the endoscope on the bundled phantom, with every optional part: the
// plans verified (one motion solved at least), a placed baseline verified too, a baseline that
// could not be placed, given ports, selection criteria (one not measured).
const Written& Plan() {
  static Written w = [] {
    Written w;
    ProblemOptions po;
    po.arms = {"psm1", "ecm"};
    po.samples_per_target = 2;
    // The case's table (not searched): the 60 evaluations below find a plan with a solved motion
    // there, which the round trip needs; with the table searched they find other plans.
    po.table_height_min = po.table_height_max = std::nan("");
    w.problem = std::make_unique<PortPlacementProblem>(Phantom(), Cart(), po);
    w.options.evaluations = 60;
    w.options.starts = 2;
    w.options.polish_evaluations = 6;
    w.options.top_k = 2;
    w.options.threads = 2;
    w.options.time_limit = 600;
    w.options.remedies = false;
    PortPlacementResult result = OptimizePorts(*w.problem, w.options);
    Baseline placed;
    placed.kind = "template";
    placed.name = "a template";
    placed.placed = true;
    placed.fixed.plan = result.plans.front();
    placed.fixed.ports.source = "a citation";
    placed.fixed.ports.where = {"ICS-L5 AAL", "ICS-L3 MCL"};
    placed.fixed.ports.notes = {"approximated"};
    placed.fixed.search = "cart searched";
    placed.fixed.evaluations = 12;
    placed.fixed.verdict = result.verdict;
    Baseline not_placed;
    not_placed.kind = "surgeon";
    not_placed.name = "ports.mrk.json";
    not_placed.why_not = "the spaces are not numbered";
    result.baselines = {placed, not_placed};
    result.ports_given = "surgeon: ports.mrk.json";
    result.ports_where = {"a", "b"};
    Criterion measured{"heart_to_chest_wall",
                       "left ventricle to the chest wall",
                       21.5,
                       "mm",
                       15,
                       true,
                       "relative contraindication",
                       "a source",
                       "how"};
    Criterion unmeasured = measured;
    unmeasured.name = "lad_depth";
    unmeasured.value = std::numeric_limits<double>::quiet_NaN();
    result.criteria.criteria = {measured, unmeasured};
    result.criteria_comparison = "agree";
    MotionOptions mo;
    mo.time_limit = 0.5;
    std::vector<PlanVerification> verifications;
    for (const RankedPlan& plan : result.plans)
      verifications.push_back(VerifyPlan(*w.problem, plan, mo, 0.8, 2));
    RankByVerification(&result, &verifications);
    const std::vector<PlanVerification> baseline = {
        VerifyPlan(*w.problem, result.baselines[0].fixed.plan, mo, 0.8, 2)};
    PlanInputs inputs;
    inputs.case_dir = test::SourcePath("patients/phantom-default");
    inputs.robot_file = test::SourcePath("robots/davinci-classic/cart.yaml");
    inputs.case_hash = HashFile(JoinPath(inputs.case_dir, "patient.yaml"));
    inputs.robot_hash = HashFile(inputs.robot_file);
    inputs.model_hash = HashPatientModel(*Phantom());
    const std::string dir = test::ScratchPath("plan_file_round_trip");
    WritePlanFolder(dir, *w.problem, result, w.options, inputs, [&](PlanFile* file) {
      AddVerification(file, *w.problem, verifications, baseline);
    });
    w.path = JoinPath(dir, "plan.json");
    w.text = ReadTextFile(w.path);
    return w;
  }();
  return w;
}

// Every key path of a document, arrays collapsed ("plans[].verification.motions[].waypoints").
void KeyPaths(const json& j, const std::string& at, std::set<std::string>* out) {
  if (j.is_object()) {
    for (const auto& [k, v] : j.items()) {
      out->insert(at + (at.empty() ? "" : ".") + k);
      KeyPaths(v, at + (at.empty() ? "" : ".") + k, out);
    }
  } else if (j.is_array()) {
    for (const auto& v : j) KeyPaths(v, at + "[]", out);
  }
}

TEST(PlanFile, WrittenThenReadThenWrittenAgainKeepsItsBytes) {
  const Written& w = Plan();
  const PlanFile file = ReadPlanFile(w.path);
  EXPECT_EQ(PlanFileText(file), w.text);
  // Every part was there to be kept.
  ASSERT_EQ(file.plans.size(), 2u);
  EXPECT_TRUE(file.plans[0].verified);
  EXPECT_TRUE(file.has_verified_verdict);
  int solved = 0;
  for (const StoredMotion& m : file.plans[0].motions) solved += m.solved && m.waypoints.size() >= 2;
  EXPECT_GT(solved, 0);
  ASSERT_EQ(file.baselines.size(), 2u);
  EXPECT_TRUE(file.baselines[0].plan.verified);
  ASSERT_TRUE(file.baselines[0].verified.has_value());
  EXPECT_FALSE(file.baselines[1].placed);
  ASSERT_EQ(file.criteria.size(), 2u);
  EXPECT_TRUE(std::isnan(file.criteria[1].value));
  EXPECT_TRUE(file.ports_given.has_value());
  EXPECT_TRUE(file.operation.has_value());
  bool scope_reach = false, instrument_reach = false;
  for (const StoredReach& r : file.plans[0].reaches)
    (r.endoscope ? scope_reach : instrument_reach) = true;
  EXPECT_TRUE(scope_reach && instrument_reach);
}

// Version 3 added the cart's z and table_height. A version-2 file (no such fields; its cart on
// z = 0) is read as the plan it was, with the case's table; a raised cart's pose is checked
// against its z; versions outside 2..3 are refused naming what this trocar reads.
TEST(PlanFile, AVersionTwoFileIsReadWithItsCartOnTheFloorAndOthersAreRefused) {
  const json now = json::parse(Plan().text);
  EXPECT_EQ(now["version"], kPlanFormatVersion);
  json old = now;
  old["version"] = 2;
  for (auto& plan : old["plans"]) {
    plan["cart"].erase("z");
    plan["cart"].erase("table_height");
  }
  const std::string dir = test::ScratchPath("plan_file_versions");
  std::filesystem::create_directories(dir);
  const std::string old_path = JoinPath(dir, "old.json");
  WriteFileAtomically(old_path, old.dump(1));
  const PlanFile file = ReadPlanFile(old_path);
  ASSERT_EQ(file.plans.size(), now["plans"].size());
  EXPECT_EQ(file.plans[0].cart_z, 0.0);
  EXPECT_TRUE(std::isnan(file.plans[0].table_height));
  // A cart raised in the file's X_WB but not in its z: one pose, not two.
  json raised = now;
  raised["plans"][0]["cart"]["X_WB"][2][3] = -0.1;
  const std::string raised_path = JoinPath(dir, "raised.json");
  WriteFileAtomically(raised_path, raised.dump(1));
  try {
    ReadPlanFile(raised_path);
    ADD_FAILURE() << "a cart off its z was read";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("plans[0].cart"), std::string::npos) << e.what();
  }
  raised["plans"][0]["cart"]["z"] = -0.1;
  WriteFileAtomically(raised_path, raised.dump(1));
  EXPECT_DOUBLE_EQ(ReadPlanFile(raised_path).plans[0].X_WB.translation().z(), -0.1);
  // A floor no table's travel puts there, and a table height no table has: named.
  for (const auto& [field, value] :
       {std::make_pair("z", 1e300), std::make_pair("table_height", 7.0)}) {
    json bad = now;
    bad["plans"][0]["cart"][field] = value;
    if (std::string(field) == "z") bad["plans"][0]["cart"]["X_WB"][2][3] = value;
    WriteFileAtomically(raised_path, bad.dump(1));
    try {
      ReadPlanFile(raised_path);
      ADD_FAILURE() << field << " " << value << " was read";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(std::string("plans[0].cart.") + field),
                std::string::npos)
          << e.what();
    }
  }
  for (int version : {1, 4}) {
    json other = now;
    other["version"] = version;
    const std::string path = JoinPath(dir, "v" + std::to_string(version) + ".json");
    WriteFileAtomically(path, other.dump(1));
    try {
      ReadPlanFile(path);
      ADD_FAILURE() << "version " << version << " was read";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find("reads versions 2 to 3"), std::string::npos) << e.what();
    }
  }
}

TEST(PlanFile, EveryDocumentedFieldIsWritten) {
  // docs/plan-format.md's fields, as key paths: a writer that leaves one out (and a reader that
  // never asks for it) would still round-trip; this names the one missing.
  std::set<std::string> keys;
  KeyPaths(json::parse(Plan().text), "", &keys);
  const char* documented[] = {"format",
                              "version",
                              "inputs.case",
                              "inputs.case_hash",
                              "inputs.robot",
                              "inputs.robot_hash",
                              "inputs.patient_model_hash",
                              "patient.name",
                              "patient.X_WP",
                              "robot.name",
                              "robot.arms[].name",
                              "robot.arms[].role",
                              "robot.arms[].rcm_frame",
                              "robot.arms[].tool_frame",
                              "robot.arms[].shaft_link",
                              "robot.arms[].shaft_a_L",
                              "robot.arms[].shaft_b_L",
                              "robot.arms[].joints",
                              "robot.arms[].max_reach_m",
                              "algorithm.global",
                              "algorithm.local",
                              "algorithm.seed",
                              "algorithm.starts",
                              "algorithm.evaluations_budget",
                              "algorithm.polish_evaluations",
                              "algorithm.evaluations",
                              "algorithm.global_evaluations",
                              "algorithm.best_global_score",
                              "algorithm.time_limit_s",
                              "algorithm.time_limit_hit",
                              "algorithm.grid",
                              "algorithm.top_k",
                              "algorithm.distinct_distance_m",
                              "algorithm.robustness_shift_m",
                              "algorithm.robustness_weight",
                              "scoring.weights.coverage",
                              "scoring.weights.served",
                              "scoring.weights.clearance_instrument_rib",
                              "scoring.standoff_m",
                              "scoring.rcm_depth_m",
                              "scoring.gap_search_depth_m",
                              "scoring.ik_tolerance_m",
                              "scoring.reach_restarts",
                              "scoring.scope_moves",
                              "scoring.sight_margin_m",
                              "scoring.samples_per_target",
                              "scoring.suitable_fraction",
                              "scoring.scope_half_fov_deg",
                              "verdict.suitable",
                              "verdict.summary",
                              "verdict.reasons",
                              "verdict.verified.summary",
                              "target_samples[].index",
                              "target_samples[].target",
                              "target_samples[].point",
                              "target_samples[].arc_length_m",
                              "target_samples[].p_W",
                              "target_samples[].n_W",
                              "target_samples[].aim_W",
                              "operation.state",
                              "operation.co2_mmHg",
                              "operation.heart_shift_range_m",
                              "operation.moved_targets",
                              "plans[].rank",
                              "plans[].status",
                              "plans[].score",
                              "plans[].rank_score",
                              "plans[].robust_score",
                              "plans[].degradation",
                              "plans[].collisions_at_nominal",
                              "plans[].message",
                              "plans[].ports[].s",
                              "plans[].ports[].curve_P",
                              "plans[].ports[].p_P",
                              "plans[].ports[].p_W",
                              "plans[].ports[].rcm_W",
                              "plans[].ports[].pivot",
                              "plans[].ports[].skin_allowance",
                              "plans[].ports[].anatomy",
                              "plans[].views[].frame",
                              "plans[].views[].axis_F",
                              "plans[].cart.x",
                              "plans[].cart.yaw_deg",
                              "plans[].cart.z",
                              "plans[].cart.table_height",
                              "plans[].cart.X_WB",
                              "plans[].setup_joints",
                              "plans[].q_nominal",
                              "plans[].terms[].unit",
                              "plans[].terms[].note",
                              "plans[].terms[].weight",
                              "plans[].served",
                              "plans[].samples[].q",
                              "plans[].samples[].tip_error_m",
                              "plans[].samples[].dexterity",
                              "plans[].samples[].approach_deg",
                              "plans[].samples[].seen",
                              "plans[].samples[].off_axis_deg",
                              "plans[].robustness[].shift_P",
                              "plans[].robustness[].served",
                              "plans[].verification.planner",
                              "plans[].verification.time_limit_s",
                              "plans[].verification.check_step",
                              "plans[].verification.recheck_step",
                              "plans[].verification.prismatic_weight_per_m",
                              "plans[].verification.seed",
                              "plans[].verification.claimed_coverage",
                              "plans[].verification.verified_coverage",
                              "plans[].verification.served",
                              "plans[].verification.served_fraction",
                              "plans[].verification.rank_score",
                              "plans[].verification.suitable",
                              "plans[].verification.reasons",
                              "plans[].verification.states_checked",
                              "plans[].verification.seconds",
                              "plans[].verification.threads",
                              "plans[].verification.motions[].outcome",
                              "plans[].verification.motions[].status",
                              "plans[].verification.motions[].planning_time_s",
                              "plans[].verification.motions[].simplification_time_s",
                              "plans[].verification.motions[].graph_states",
                              "plans[].verification.motions[].path_length",
                              "plans[].verification.motions[].raw_path_length",
                              "plans[].verification.motions[].tip_path_length_m",
                              "plans[].verification.motions[].min_clearance_m",
                              "plans[].verification.motions[].rechecked_states",
                              "plans[].verification.motions[].joints",
                              "plans[].verification.motions[].waypoints",
                              "ports_given.what",
                              "ports_given.where",
                              "baselines[].kind",
                              "baselines[].why_not",
                              "baselines[].source",
                              "baselines[].where",
                              "baselines[].notes",
                              "baselines[].search",
                              "baselines[].evaluations",
                              "baselines[].verdict.summary",
                              "baselines[].verdict.verified.reasons",
                              "baselines[].plan.verification.motions[].outcome",
                              "selection_criteria.criteria[].value",
                              "selection_criteria.criteria[].favourable_when",
                              "selection_criteria.criteria[].source",
                              "selection_criteria.comparison",
                              "convergence",
                              "run.threads",
                              "run.timings_s"};
  for (const char* key : documented) EXPECT_TRUE(keys.count(key)) << key << " is not written";
}

TEST(PlanFile, AFieldNothingInterpretsSurvivesARewriteAndASignOffChangesOnlyTheSignOffs) {
  const Written& w = Plan();
  json doc = json::parse(w.text);
  // Values a tool may have edited, that trocar only carries: each must come back as given (a
  // reader that skips one writes its default instead).
  doc["plans"][0]["terms"][0]["note"] = "measured by hand";
  doc["plans"][0]["samples"][0]["dexterity"] = 0.25;
  doc["plans"][1]["robustness"][0]["coverage"] = 0.125;
  doc["run"]["timings_s"]["total"] = 4.5;
  doc["selection_criteria"]["criteria"][0]["source"] = "another source";
  doc["convergence"][0][1] = 0.375;
  doc["baselines"][0]["notes"] = {"a note", "another"};
  doc["plans"][0]["verification"]["motions"][0]["planning_time_s"] = 0.0625;
  doc["algorithm"]["grid"] = "3 x 3";
  // Fields this trocar does not know (a newer one's, a tool's) are kept as they are.
  doc["hospital_extension"] = {{"ward", "B"}, {"beds", {1, 2.5, nullptr}}};
  doc["plans"][1]["reviewed_by_tool"] = true;
  const std::string edited = doc.dump(1) + "\n";
  const std::string dir = test::ScratchPath("plan_file_edited");
  std::filesystem::create_directories(dir);
  const std::string path = JoinPath(dir, "plan.json");
  WriteFileAtomically(path, edited);
  EXPECT_EQ(PlanFileText(ReadPlanFile(path)), edited);

  // A sign-off goes through the same writer: the file afterwards is the file before with one
  // sign-off added to the plan signed, and it round-trips as well.
  SignOff s;
  s.decision = "rejected";
  s.surgeon = "Dr Ada";
  s.note = "ports too close";
  const SignOff written = SignOffPlan(path, 1, s);
  const std::string after = ReadTextFile(path);
  EXPECT_EQ(PlanFileText(ReadPlanFile(path)), after);
  json expected = doc;
  expected["plans"][1]["signoffs"] = json::array({{{"decision", "rejected"},
                                                   {"surgeon", "Dr Ada"},
                                                   {"note", "ports too close"},
                                                   {"time", written.time}}});
  EXPECT_EQ(json::parse(after), expected);
}

TEST(PlanFile, VerifyRebuildsTheProblemAndThePlansAsTheyWereScored) {
  const Written& w = Plan();
  const PlanFile file = ReadPlanFile(w.path);
  const ProblemOptions po = PlanProblemOptions(file);
  EXPECT_EQ(po.arms, (std::vector<std::string>{"psm1", "ecm"}));
  EXPECT_EQ(po.samples_per_target, 2);
  const ProblemOptions& was = w.problem->options();
  EXPECT_EQ(po.weights.coverage, was.weights.coverage);
  EXPECT_EQ(po.weights.clearance_instrument_rib, was.weights.clearance_instrument_rib);
  EXPECT_EQ(po.scope_moves, was.scope_moves);
  EXPECT_NEAR(po.scope_half_fov, was.scope_half_fov, 1e-12);
  EXPECT_EQ(po.seed, w.options.seed);
  const PortPlacementProblem problem(Phantom(), Cart(), po);
  for (std::size_t k = 0; k < file.plans.size(); ++k) {
    const RankedPlan plan = RestorePlan(problem, file, k);
    const StoredPlan& stored = file.plans[k];
    ASSERT_EQ(plan.placement.sites.size(), stored.ports.size());
    for (std::size_t a = 0; a < stored.ports.size(); ++a)
      EXPECT_LT((plan.placement.sites[a].p_W - stored.ports[a].p_W).norm(), 1e-4);
    EXPECT_LT((plan.placement.X_WB().matrix() - stored.X_WB.matrix()).norm(), 1e-9);
    EXPECT_EQ(plan.evaluation.score, stored.score);
    // The nominal pose as stored: every named joint at its value.
    for (const auto& [name, value] : stored.q_nominal)
      EXPECT_EQ(plan.evaluation.q_nominal[Cart()->joint(Cart()->FindJoint(name)).q_index], value);
  }
  // A weight the file lacks is named (a plan that has lost its scoring cannot be re-verified).
  PlanFile broken = file;
  broken.scoring.weights.erase(broken.scoring.weights.begin());
  try {
    (void)PlanProblemOptions(broken);
    ADD_FAILURE() << "a missing weight was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("scoring.weights.approach: missing"), std::string::npos)
        << e.what();
  }
}

}  // namespace
}  // namespace trocar::planners
