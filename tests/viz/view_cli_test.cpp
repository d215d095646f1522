// trocar view on a real plan of the bundled case: screenshots, replay of verified motions, the
// window, and bad input. The plan is made once for the suite by `trocar plan` (small budget).
#include <fcntl.h>
#include <gtest/gtest.h>
#include <sys/file.h>
#include <sys/wait.h>
#include <unistd.h>

#include <array>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <random>
#include <set>
#include <thread>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/limits.hpp"
#include "control/igtl_device.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "plan/plan_file.hpp"
#include "plan/reachability.hpp"
#include "plan/signoff.hpp"
#include "projection.hpp"
#include "replay.hpp"
#include "robot/load_robot.hpp"
#include "scene.hpp"
#include "scene_file.hpp"
#include "test_util.hpp"
#include "view_inputs.hpp"
#include "workstation.hpp"

namespace trocar::viz {
namespace {

using test::SourcePath;

using test::CommandRun;

CommandRun Shell(const std::string& command) { return test::RunShell(command); }

CommandRun Trocar(const std::string& arguments) {
  return Shell("cd " + SourcePath("") + " && " + std::string(TROCAR_BINARY) + " " + arguments);
}

class ViewCli : public ::testing::Test {
 protected:
  /// The plan is made once for every test process (ctest runs each test alone, two at a time):
  /// under a lock, into the build tree, again whenever the trocar binary changed.
  static void SetUpTestSuite() {
    dir_ = (std::filesystem::temp_directory_path() / ("trocar_view_" + std::to_string(::getpid()))).string();
    std::filesystem::create_directories(dir_);
    std::filesystem::create_directories(TROCAR_TEST_WORK_DIR);
    const int lock = ::open((std::string(TROCAR_TEST_WORK_DIR) + "/plan.lock").c_str(), O_CREAT | O_RDWR, 0644);
    ASSERT_GE(lock, 0);
    ASSERT_EQ(::flock(lock, LOCK_EX), 0);
    const auto stamp_of_binary = std::to_string(
        std::filesystem::last_write_time(TROCAR_BINARY).time_since_epoch().count());
    const std::string stamp = std::string(TROCAR_TEST_WORK_DIR) + "/plan.stamp";
    if (!IsRegularFile(Plan()) || !IsRegularFile(stamp) || ReadTextFile(stamp) != stamp_of_binary) {
      const CommandRun plan =
          Trocar("plan --no-remedies " + SourcePath("patients/phantom-default") + " --robot " +
                 SourcePath("robots/davinci-classic/cart.yaml") +
                 " --arms psm1 psm2 --evaluations 300 --starts 2 --motion-time 0.5 --baseline none "
                 // The case's table (held): the suite's premises (a LAD
                 // sample reached, a plan to override) were found there.
                 "--table-height fixed --out " +
                 std::string(TROCAR_TEST_WORK_DIR) + "/plan");
      EXPECT_TRUE(plan.exit_code == 0 || plan.exit_code == 4) << plan.output;
      if (plan.exit_code == 0 || plan.exit_code == 4) WriteFileAtomically(stamp, stamp_of_binary);
    }
    ::flock(lock, LOCK_UN);
    ::close(lock);
  }
  static void TearDownTestSuite() { std::filesystem::remove_all(dir_); }
  static std::string Plan() { return std::string(TROCAR_TEST_WORK_DIR) + "/plan/plan.json"; }
  static std::string Out(const std::string& name) { return dir_ + "/" + name; }
  static std::string dir_;
};
std::string ViewCli::dir_;

/// The flat colours the CLI is given, so that a pixel names its group.
const char* kFlat = " --flat --colour robot=0,0,255 --colour table=0,255,0 --colour skin=255,128,0 "
                    "--colour background=0,0,0 --opacity skin=1 ";

long CountRgb(const Image& image, int r, int g, int b) {
  long n = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const auto p = image.Pixel(x, y);
      n += std::abs(p[0] - r) <= 2 && std::abs(p[1] - g) <= 2 && std::abs(p[2] - b) <= 2;
    }
  return n;
}

TEST_F(ViewCli, AScreenshotShowsThePatientAndTheRobotAtThePlansPose) {
  const std::string png = Out("nominal.png");
  const CommandRun run = Trocar("view patients/phantom-default " + Plan() + kFlat +
                                "--view external --size 640x400 --screenshot " + png);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const Image image = ReadPng(png);
  ASSERT_EQ(image.width, 640);
  ASSERT_EQ(image.height, 400);
  EXPECT_GT(CountRgb(image, 0, 0, 255), 640 * 400 / 50) << "robot";
  EXPECT_GT(CountRgb(image, 0, 255, 0), 640 * 400 / 50) << "table";
  EXPECT_GT(CountRgb(image, 255, 128, 0), 640 * 400 / 200) << "skin";
}

TEST_F(ViewCli, ReplayDrawsTheArmAtTheMotionsWaypoints) {
  const planners::PlanFile file = planners::ReadPlanFile(Plan());
  const planners::StoredMotion* motion = nullptr;
  for (const auto& m : file.plans[0].motions)
    if (m.solved && m.waypoints.size() >= 2 && !motion) motion = &m;
  ASSERT_NE(motion, nullptr) << "the suite's plan has no solved motion to replay";
  const std::string id = motion->arm + ":" + std::to_string(motion->sample);
  auto shot = [&](const std::string& extra, const std::string& name) {
    const CommandRun run = Trocar("view patients/phantom-default " + Plan() + kFlat +
                                  "--view external --size 480x320 " + extra + " --screenshot " + Out(name));
    EXPECT_EQ(run.exit_code, 0) << run.output;
    return ReadPng(Out(name));
  };
  const Image nominal = shot("", "n.png");
  const Image first = shot("--motion " + id + ":0", "first.png");
  const Image last = shot("--motion " + id, "last.png");
  // The first waypoint is the nominal pose; the last (at the target) is elsewhere.
  EXPECT_EQ(first.rgb, nominal.rgb);
  EXPECT_NE(last.rgb, nominal.rgb);

  // In process: at the last waypoint, every link shape a few pixels wide is drawn where forward
  // kinematics of the waypoint's joint values puts it.
  ViewInputs in;
  in.case_dir = file.case_dir;
  in.plan = Plan();
  in.motion = id;
  in.flat = true;
  LoadedView view = LoadView(in);
  for (const std::string& g : view.scene->groups())
    if (g != "robot") view.scene->SetVisible(g, false);
  view.scene->SetColour("robot", {0, 0, 1});
  view.scene->HighlightLinks({}, {});  // near misses are drawn in their own colour
  const robot::RobotState& state = *view.scene->robot_state();
  const int arm_link = view.robot->FindLink(motion->arm + "_insertion_link");
  ASSERT_GE(arm_link, 0);
  const Eigen::Vector3d p_W = state.X_WL[arm_link] * view.robot->link(arm_link).collisions[0].X_LG.translation();
  CameraPose camera;
  camera.focal_point = p_W;
  camera.position = p_W + Eigen::Vector3d(0.3, -0.5, 0.4);
  camera.view_angle_deg = 30;
  const Image image = Render(*view.scene, {{ViewSpec{}, camera}}, 200, 200);
  EXPECT_EQ(image.Pixel(100, 100), (std::array<std::uint8_t, 3>{0, 0, 255}))
      << "the instrument carriage at the motion's last waypoint is not where its joints put it";
}

TEST_F(ViewCli, TheEndoscopeViewIsDrawnFromThePlansScopeFrame) {
  // A plan names its scope's camera frame (here, for the test, psm1's tool); the endoscope view
  // renders from that frame, as a camera put on it by name does.
  const std::string png = Out("scope.png");
  nlohmann::json doc = nlohmann::json::parse(ReadTextFile(Plan()));
  doc["plans"][0]["views"] = nlohmann::json::array({{{"arm", "ecm"}, {"frame", "psm1_tool"}, {"axis_F", {0, 0, 1}}}});
  const std::string edited = Out("scope_plan.json");
  WriteFileAtomically(edited, doc.dump());
  const CommandRun run = Trocar("view patients/phantom-default " + edited + kFlat +
                                "--view endoscope --size 300x300 --screenshot " + png);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const Image scope = ReadPng(png);
  const CommandRun run2 = Trocar("view patients/phantom-default " + edited + kFlat +
                                 "--view frame:psm1_tool --size 300x300 --screenshot " + png + "2");
  ASSERT_EQ(run2.exit_code, 0) << run2.output;
  EXPECT_EQ(scope.rgb, ReadPng(png + "2").rgb);
}

TEST_F(ViewCli, CollisionsOfTheShownPoseAreSaidAndDrawnInTheCollisionColour) {
  const std::string flat = std::string(kFlat) + "--colour collision=255,0,255 --view external --size 480x320 ";
  const CommandRun free = Trocar("view patients/phantom-default " + Plan() + flat + "--screenshot " + Out("free.png"));
  ASSERT_EQ(free.exit_code, 0) << free.output;
  EXPECT_NE(free.output.find("robot pose: collision-free, clearance"), std::string::npos) << free.output;
  EXPECT_EQ(CountRgb(ReadPng(Out("free.png")), 255, 0, 255), 0);
  // An instrument at the LAD sample it reaches most head-on, then pushed 6 cm further in: into
  // the heart, whatever the plan's ports.
  nlohmann::json doc = nlohmann::json::parse(ReadTextFile(Plan()));
  const nlohmann::json* best = nullptr;
  for (const auto& r : doc["plans"][0]["samples"]) {
    if (!r["reached"].get<bool>() || r["arm"].get<std::string>().rfind("psm", 0) != 0) continue;
    // A sample on the heart (pushed in, the tool goes into it; one on the chest wall's inner
    // face may run out between two ribs).
    if (doc["target_samples"][r["sample"].get<int>()]["target"] != "LAD") continue;
    if (!best || r["approach_deg"].get<double>() < (*best)["approach_deg"].get<double>()) best = &r;
  }
  ASSERT_TRUE(best && (*best)["approach_deg"].get<double>() < 80)
      << "the suite's plan reaches no LAD sample within 80 degrees of its normal";
  const std::string arm = (*best)["arm"].get<std::string>();
  for (const auto& [name, value] : (*best)["q"].items()) doc["plans"][0]["q_nominal"][name] = value;
  // Seen from the room: the external view looks at the chest from where an arm may stand.
  const std::string room = std::string(kFlat) + "--colour collision=255,0,255 --view room --size 480x320 ";
  // Pushed in 6 cm, and further while it slides along the heart's surface (an approach far from
  // the surface's normal), until the view says it collides.
  CommandRun deep;
  for (double push = 0.06; push <= 0.15 + 1e-9; push += 0.03) {
    doc["plans"][0]["q_nominal"][arm + "_outer_insertion"] =
        (*best)["q"][arm + "_outer_insertion"].get<double>() + push;
    WriteFileAtomically(Out("deep.json"), doc.dump());
    deep = Trocar("view patients/phantom-default " + Out("deep.json") + room + "--screenshot " + Out("deep.png"));
    ASSERT_EQ(deep.exit_code, 0) << deep.output;
    if (deep.output.find("robot pose: in collision") != std::string::npos) break;
  }
  EXPECT_NE(deep.output.find("robot pose: in collision: " + arm + "_"), std::string::npos) << deep.output;
  EXPECT_GT(CountRgb(ReadPng(Out("deep.png")), 255, 0, 255), 20);
}

// Issue #43 item 2: a close-up of the ports on the chest for every plan. In the ports view every
// port lies inside the picture, away from its edges, and the ports spread over at least half of
// its height (it frames them with 3 cm of chest around); the whole-chest view spreads them less.
TEST_F(ViewCli, ThePortsViewShowsThePortsOnTheChestClose) {
  ViewInputs in;
  in.case_dir = planners::ReadPlanFile(Plan()).case_dir;
  in.plan = Plan();
  in.flat = true;
  LoadedView view = LoadView(in);
  const int w = 640, h = 400;
  auto spread = [&](const std::string& name) {
    const ViewSpec spec = ViewSpec::Parse(name);
    const CameraPose camera =
        ViewCamera(*view.scene, spec, double(w) / h, &view.plan->plans[0], nullptr);
    std::vector<Eigen::Vector2d> px;
    for (const auto& port : view.plan->plans[0].ports) {
      Eigen::Vector2d p;
      EXPECT_TRUE(test_projection::Project(camera, w, h, port.p_W, &p)) << port.arm;
      EXPECT_TRUE(p.x() > 0.05 * w && p.x() < 0.95 * w && p.y() > 0.05 * h && p.y() < 0.95 * h)
          << name << ": " << port.arm << " at " << p.transpose();
      px.push_back(p);
    }
    double most = 0;
    for (const auto& a : px)
      for (const auto& b : px) most = std::max(most, (a - b).norm());
    return most;
  };
  ASSERT_GE(view.plan->plans[0].ports.size(), 2u);
  const double close = spread("ports"), whole = spread("external");
  EXPECT_GE(close, 0.5 * h) << "the ports spread " << close << " px of " << h;
  EXPECT_GT(close, whole) << "the ports spread " << close << " px close up, " << whole
                          << " in the chest view";
  EXPECT_THROW(ViewSpec::Parse("portz"), Error);
}

// Issue #43 item 9: a failed motion is shown at the pose where it fails, with its reason. The
// verification keeps that pose (an unreachable sample's inverse-kinematics answer, in collision
// or at a limit); the view poses the arm there and says why; the replay runs from the nominal
// pose to it. A plan's motion made to fail by the test (its instrument pushed into the heart)
// shows the same.
TEST_F(ViewCli, AFailedMotionIsShownAtThePoseWhereItFails) {
  planners::PlanFile file = planners::ReadPlanFile(Plan());
  int real = 0;
  for (std::size_t k = 0; k < file.plans.size(); ++k) {
    for (const auto& m : file.plans[k].motions) {
      if (m.solved || m.outcome != "unreachable") continue;
      SCOPED_TRACE(m.arm + ":" + std::to_string(m.sample) + " " + m.reason);
      ASSERT_EQ(m.failure_pose.size(), static_cast<Eigen::Index>(m.joints.size()));
      if (m.reason.find("not valid: collision") == std::string::npos) continue;
      ViewInputs in;
      in.case_dir = file.case_dir;
      in.plan = Plan();
      in.plan_index = static_cast<int>(k) + 1;
      in.motion = m.arm + ":" + std::to_string(m.sample);
      const LoadedView view = LoadView(in);
      EXPECT_TRUE(view.pose.collision) << "the stored pose where it fails does not collide";
      EXPECT_EQ(view.failure, m.outcome + ": " + m.reason);
      ++real;
    }
  }
  std::cout << real << " motions of the suite's plan fail in collision and were shown\n";
  // A solved motion to an LAD sample turned into a failure: its last waypoint pushed 6 cm and
  // further along the insertion until the view says it collides.
  planners::StoredPlan& plan = file.plans[0];
  planners::StoredMotion* chosen = nullptr;
  for (auto& m : plan.motions)
    if (m.solved && m.arm == "psm1" && file.samples[m.sample].target == "LAD") chosen = &m;
  ASSERT_TRUE(chosen) << "the suite's plan has no solved psm1 motion to the LAD";
  const std::size_t insertion = static_cast<std::size_t>(
      std::find(chosen->joints.begin(), chosen->joints.end(), "psm1_outer_insertion") -
      chosen->joints.begin());
  ASSERT_LT(insertion, chosen->joints.size());
  const Eigen::VectorXd at_target = chosen->waypoints.back();
  chosen->solved = false;
  chosen->has_path = false;
  chosen->outcome = "unreachable";
  chosen->reason = "set by the test";
  chosen->waypoints.clear();
  const std::string id = "psm1:" + std::to_string(chosen->sample);
  CommandRun run;
  for (double push = 0.06; push <= 0.15 + 1e-9; push += 0.03) {
    chosen->failure_pose = at_target;
    chosen->failure_pose[static_cast<Eigen::Index>(insertion)] += push;
    planners::WritePlanFile(Out("failed.json"), file);
    run = Trocar("view patients/phantom-default " + Out("failed.json") + kFlat + "--motion " + id +
                 " --colour collision=255,0,255 --view room --size 480x320 --screenshot " +
                 Out("failed.png"));
    ASSERT_EQ(run.exit_code, 0) << run.output;
    if (run.output.find("robot pose: in collision") != std::string::npos) break;
  }
  EXPECT_NE(
      run.output.find("motion " + id +
                      " fails: unreachable: set by the test; shown at the pose where it fails"),
      std::string::npos)
      << run.output;
  EXPECT_NE(run.output.find("robot pose: in collision: psm1_"), std::string::npos) << run.output;
  EXPECT_GT(CountRgb(ReadPng(Out("failed.png")), 255, 0, 255), 20)
      << "the failing links in the collision colour";
  // The replay: from the nominal pose to the failing one, which is its last frame and collides.
  ViewInputs in;
  in.case_dir = file.case_dir;
  in.plan = Out("failed.json");
  const LoadedView view = LoadView(in);
  const planners::StoredMotion* failed = nullptr;
  for (const auto& m : view.plan->plans[0].motions)
    if (m.arm == "psm1" && m.sample == chosen->sample) failed = &m;
  ASSERT_TRUE(failed);
  const std::vector<ReplayFrame> frames =
      ReplayMotion(*view.robot, *view.scene->robot_state(), *failed, view.collisions.get());
  ASSERT_GE(frames.size(), 2u);
  EXPECT_EQ(frames.front().state.q, view.scene->robot_state()->q) << "starts at the nominal pose";
  const int j = view.robot->joint(view.robot->FindJoint("psm1_outer_insertion")).q_index;
  EXPECT_DOUBLE_EQ(frames.back().state.q[j],
                   chosen->failure_pose[static_cast<Eigen::Index>(insertion)]);
  EXPECT_TRUE(frames.back().collisions.collision);
  // A waypoint of a motion that has none is refused, naming it.
  in.motion = id + ":2";
  EXPECT_THROW(LoadView(in), Error);
}

TEST_F(ViewCli, TheWindowShowsTheSidebarAndTheScene) {
  const std::string png = Out("window.png");
  const CommandRun run = Trocar("view patients/phantom-default " + Plan() + kFlat + "--grab " + png);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const Image image = ReadPng(png);
  ASSERT_GE(image.width, 800);
  // The scene (right of the sidebar) shows the robot in its flat colour; the sidebar is not.
  long robot_right = 0, robot_left = 0;
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const auto p = image.Pixel(x, y);
      if (p[0] <= 2 && p[1] <= 2 && p[2] >= 253) (x < 300 ? robot_left : robot_right)++;
    }
  EXPECT_GT(robot_right, 2000);
  EXPECT_EQ(robot_left, 0);
}

TEST_F(ViewCli, ASignOffIsAddedToItsPlanAndEverythingElseInTheFileIsKept) {
  const std::string path = Out("signed.json");
  WriteFileAtomically(path, ReadTextFile(Plan()));
  const nlohmann::json before = nlohmann::json::parse(ReadTextFile(path));
  const std::string session = Out("session.csv");
  WriteFileAtomically(session, "t,x\n0,1\n");
  // The fixture's plan 2 fails (the two-arm default is not suitable): approving it is refused,
  // naming why, and nothing is written; with an override and its reason it is recorded as such.
  const std::vector<std::string> blockers = planners::ApprovalBlockers(planners::ReadPlanFile(path), 1);
  ASSERT_FALSE(blockers.empty()) << "premise: the fixture's plan 2 fails";
  CommandRun run = Trocar("signoff " + path + " --plan 2 --approve --surgeon 'Dr Ada' --note 'ports fine'");
  EXPECT_EQ(run.exit_code, 1) << run.output;
  EXPECT_NE(run.output.find("cannot be approved"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find(blockers[0]), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("--override"), std::string::npos) << run.output;
  EXPECT_EQ(nlohmann::json::parse(ReadTextFile(path)), before);
  run = Trocar("signoff " + path + " --plan 2 --approve --surgeon 'Dr Ada' --note 'ports fine' --session " +
               session + " --override 'teaching case, not operated'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("plan 2: approved"), std::string::npos) << run.output;
  run = Trocar("signoff " + path + " --plan 2 --reject --surgeon 'Dr Bea' --note 'LIMA too far'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("plan 2: rejected"), std::string::npos) << run.output;
  const planners::PlanFile file = planners::ReadPlanFile(path);
  EXPECT_EQ(planners::PlanDecisionStatus(file, 1), "rejected");
  ASSERT_EQ(file.plans[1].signoffs.size(), 2u);
  EXPECT_EQ(file.plans[1].signoffs[0].decision, "approved");
  EXPECT_EQ(file.plans[1].signoffs[0].override_reason, "teaching case, not operated");
  EXPECT_EQ(file.plans[1].signoffs[0].overridden, blockers);
  EXPECT_TRUE(file.plans[1].signoffs[1].override_reason.empty());
  EXPECT_EQ(file.plans[1].signoffs[0].surgeon, "Dr Ada");
  EXPECT_EQ(file.plans[1].signoffs[0].session, session);
  EXPECT_EQ(file.plans[1].signoffs[0].session_hash.rfind("fnv1a64:", 0), 0u);
  EXPECT_EQ(file.plans[1].signoffs[1].decision, "rejected");
  EXPECT_EQ(file.plans[1].signoffs[1].note, "LIMA too far");
  EXPECT_EQ(file.plans[1].signoffs[1].time.size(), 20u);  // 2026-11-25T17:46:36Z
  EXPECT_TRUE(file.plans[0].signoffs.empty());
  nlohmann::json after = nlohmann::json::parse(ReadTextFile(path));
  after["plans"][1].erase("signoffs");
  EXPECT_EQ(after, before);
  // Refused, the file untouched.
  const std::string kept = ReadTextFile(path);
  for (const char* bad : {"--plan 9 --approve --surgeon x", "--approve --reject --surgeon x",
                          "--surgeon x", "--approve --surgeon x --override y --session /no/such.csv",
                          "--plan 2 --approve --surgeon x", "--plan 2 --reject --surgeon x --override y"}) {
    run = Trocar("signoff " + path + " " + bad);
    EXPECT_NE(run.exit_code, 0) << bad;
    EXPECT_EQ(ReadTextFile(path), kept) << bad;
  }
}

TEST_F(ViewCli, HostilePlanFilesAreRefusedNamingTheFieldByEveryReaderAndNothingIsWritten) {
  // #44 item 1, one class each: deep nesting, a repeated key, a wrong type, an integer that wraps
  // when narrowed, a cart pose disagreeing with itself, a shifted index, too many values. Each is
  // refused by the typed reader (view, report, signoff) with the field named, by `check --plan`
  // and `verify` as a bad input (exit 1, not a crash, not "all hold"), and signoff writes nothing.
  const nlohmann::json good = nlohmann::json::parse(ReadTextFile(Plan()));
  const std::string text = good.dump();
  struct Case {
    std::string name, text, says;
  };
  std::vector<Case> cases;
  cases.push_back({"deep", text.substr(0, text.size() - 1) + ",\"x\":" + std::string(100000, '[') +
                               std::string(100000, ']') + "}",
                   "nested deeper than"});
  cases.push_back({"duplicate", text.substr(0, text.size() - 1) + ",\"plans\":[]}",
                   "plans: the key is given twice"});
  nlohmann::json doc = good;
  doc["plans"] = nlohmann::json::object();
  cases.push_back({"object", doc.dump(), "plans: expected an array"});
  doc = good;
  doc["plans"] = nlohmann::json::array();
  cases.push_back({"empty", doc.dump(), "at least one plan"});
  doc = good;
  doc["version"] = 4294967298ull;  // 2 + 2^32: read as 2 once narrowed unchecked
  cases.push_back({"version", doc.dump(), "version: expected an integer"});
  doc = good;
  doc["plans"][0]["cart"]["X_WB"][0][3] = doc["plans"][0]["cart"]["X_WB"][0][3].get<double>() + 0.25;
  cases.push_back(
      {"cart", doc.dump(), "plans[0].cart: expected X_WB to agree with x, y, z and yaw_deg"});
  doc = good;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) doc["plans"][0]["cart"]["X_WB"][r][c] = 2 * doc["plans"][0]["cart"]["X_WB"][r][c].get<double>();
  cases.push_back({"scaled", doc.dump(), "plans[0].cart.X_WB: expected a rigid transform"});
  doc = good;
  ASSERT_FALSE(doc["plans"][0]["verification"]["motions"].empty());
  doc["plans"][0]["verification"]["motions"][0]["sample"] =
      doc["plans"][0]["verification"]["motions"][0]["sample"].get<std::int64_t>() + (std::int64_t{1} << 32);
  cases.push_back({"index", doc.dump(), "plans[0].verification.motions[0].sample: expected an integer"});
  // Written, then refused by the typed reader naming the field and the file; returns the path.
  auto refused_by_reader = [&](const Case& c) {
    const std::string path = Out("hostile_" + c.name + ".json");
    WriteFileAtomically(path, c.text);
    try {
      planners::ReadPlanFile(path);
      ADD_FAILURE() << c.name << ": read";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(c.says), std::string::npos) << c.name << ": " << e.what();
      EXPECT_NE(std::string(e.what()).find(path), std::string::npos) << c.name << ": " << e.what();
    }
    return path;
  };
  for (const Case& c : cases) {
    const std::string path = refused_by_reader(c);
    for (const std::string& command : {"check --plan " + path, "signoff " + path + " --reject --surgeon x",
                                      "verify " + path + " --motion-time 0.1"}) {
      const CommandRun run = Trocar(command);
      EXPECT_EQ(run.exit_code, 1) << c.name << ": " << command << "\n" << run.output;
      EXPECT_NE(run.output.find(c.says), std::string::npos) << c.name << ": " << command << "\n" << run.output;
    }
    EXPECT_EQ(ReadTextFile(path), c.text) << c.name;
  }
  // Physical ranges, by the typed reader (which check --plan, verify and signoff read through
  // first): a port at 1e308, a joint at 1e300 rad, a rank below 1 or fractional, a normal that is
  // not a unit vector.
  std::vector<Case> ranges;
  doc = good;
  doc["plans"][0]["ports"][0]["p_W"][0] = 1e308;
  ranges.push_back({"port", doc.dump(), "plans[0].ports[0].p_W: expected a point within 100 m"});
  doc = good;
  doc["plans"][0]["q_nominal"][doc["plans"][0]["q_nominal"].begin().key()] = 1e300;
  ranges.push_back({"joint", doc.dump(), "expected a joint value within 1000"});
  doc = good;
  doc["plans"][0]["rank"] = -1;
  ranges.push_back({"rank", doc.dump(), "plans[0].rank: expected a rank from 1"});
  doc = good;
  doc["plans"][0]["rank"] = 1.5;
  ranges.push_back({"fraction", doc.dump(), "plans[0].rank: expected an integer"});
  doc = good;
  doc["target_samples"][0]["n_W"] = {0, 0, 3};
  ranges.push_back({"normal", doc.dump(), "target_samples[0].n_W: expected a unit vector"});
  doc = good;
  {
    // One motion more than one per arm and sample.
    auto& motions = doc["plans"][0]["verification"]["motions"];
    const std::size_t most = doc["robot"]["arms"].size() * doc["target_samples"].size();
    while (motions.size() <= most) motions.push_back(motions[0]);
  }
  ranges.push_back({"motions", doc.dump(), "more than one per arm"});
  // A failed motion's pose where it fails: joint values in range, one per joint, never on a
  // solved motion.
  {
    nlohmann::json motion;
    for (const auto& m : good["plans"][0]["verification"]["motions"])
      if (m["solved"].get<bool>() && motion.is_null()) motion = m;
    ASSERT_FALSE(motion.is_null()) << "the suite's plan has no solved motion";
    const std::size_t joints = motion["joints"].size();
    auto with = [&](bool solved, const nlohmann::json& pose) {
      nlohmann::json d = good, m = motion;
      m["solved"] = solved;
      m["failure_pose"] = pose;
      for (auto& each : d["plans"][0]["verification"]["motions"])
        if (each["arm"] == m["arm"] && each["sample"] == m["sample"]) each = m;
      return d.dump();
    };
    ranges.push_back({"failure far", with(false, std::vector<double>(joints, 1e300)),
                      "failure_pose[0]: expected a joint value within 1000"});
    ranges.push_back({"failure short", with(false, std::vector<double>(1, 0.0)),
                      "failure_pose: expected " + std::to_string(joints) + " joint values"});
    ranges.push_back({"failure solved", with(true, std::vector<double>(joints, 0.0)),
                      "expected no failure pose on a solved motion"});
  }
  for (const Case& c : ranges) refused_by_reader(c);
  // Too many values for the stated limit: refused while parsing, naming the limit's variable.
  InputLimits small = Limits();
  const InputLimits kept = small;
  small.max_json_values = 1000;
  SetLimits(small);
  try {
    planners::ReadPlanFile(Plan());
    ADD_FAILURE() << "read past the value limit";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("TROCAR_MAX_JSON_VALUES"), std::string::npos) << e.what();
  }
  SetLimits(kept);
  EXPECT_NO_THROW(planners::ReadPlanFile(Plan()));
}

TEST_F(ViewCli, ASignOffKilledAtAnyMomentLeavesTheOldFileOrTheNewOneWhole) {
  // A large plan file (padded), so that a kill often lands while it is being written.
  nlohmann::json doc = nlohmann::json::parse(ReadTextFile(Plan()));
  // 4 MiB in strings of 32 KiB (a JSON string is at most TROCAR_MAX_JSON_STRING, 64 KiB).
  doc["padding"] = nlohmann::json::array();
  for (int i = 0; i < 128; ++i) doc["padding"].push_back(std::string(32 << 10, 'x'));
  const std::string path = Out("killed.json");
  WriteFileAtomically(path, doc.dump());
  auto start = [&]() {
    const pid_t child = ::fork();
    if (child == 0) {
      ::execl(TROCAR_BINARY, TROCAR_BINARY, "signoff", path.c_str(), "--reject", "--surgeon", "s",
              "--note", std::string(5000, 'n').c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    return child;
  };
  // One sign-off to the end, timed; then sign-offs killed between a third of that time and a
  // little past it.
  const auto t0 = std::chrono::steady_clock::now();
  const pid_t first = start();
  ASSERT_GT(first, 0);
  int status = 0;
  ::waitpid(first, &status, 0);
  ASSERT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  const double whole_us = std::chrono::duration<double, std::micro>(std::chrono::steady_clock::now() - t0).count();
  std::size_t signed_off = planners::ReadPlanFile(path).plans[0].signoffs.size();
  ASSERT_EQ(signed_off, 1u);
  std::mt19937 rng(11);
  int completed = 0;
  for (int trial = 0; trial < 16; ++trial) {
    const pid_t child = start();
    ASSERT_GT(child, 0);
    ::usleep(static_cast<useconds_t>(std::uniform_real_distribution<double>(0.3, 1.1)(rng) * whole_us));
    ::kill(child, SIGKILL);
    ::waitpid(child, &status, 0);
    completed += WIFEXITED(status) && WEXITSTATUS(status) == 0;
    // Whatever the moment: a whole plan file, with the sign-offs it had or one more.
    const planners::PlanFile file = planners::ReadPlanFile(path);
    const std::size_t n = file.plans[0].signoffs.size();
    EXPECT_TRUE(n == signed_off || n == signed_off + 1) << n << " after " << signed_off;
    signed_off = n;
    EXPECT_EQ(nlohmann::json::parse(ReadTextFile(path))["padding"].size(), 128u);
  }
  EXPECT_LT(completed, 16) << "no sign-off was interrupted: the test proves nothing";
}

TEST(TeleopView, TheWindowShowsTheRobotTheControlThreadMovesWhileItRuns) {
  const std::string png = (std::filesystem::temp_directory_path() /
                           ("trocar_teleop_" + std::to_string(::getpid()) + ".png")).string();
  const CommandRun run = Trocar("teleop --robot robots/davinci-classic/psm.yaml --view --duration 1.5 "
                                "--input circle --fps 30 --grab " + png);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  // The renderer saw the control thread's steps as they came: a new one in nearly every frame it
  // drew (it reads the newest, never each one), far fewer than the 1500 control steps. Measured
  // against the frames this run could draw, not a frame rate: a loaded machine draws fewer.
  const auto at = run.output.find("new control steps shown");
  ASSERT_NE(at, std::string::npos) << run.output;
  const auto view = run.output.find("view: ");
  ASSERT_NE(view, std::string::npos) << run.output;
  const long frames = std::stol(run.output.substr(view + 6));
  const long shown = std::stol(run.output.substr(run.output.rfind(", ", at) + 2));
  EXPECT_GE(shown, 2) << run.output.substr(view);           // the robot moved on screen
  EXPECT_GE(4 * shown, 3 * frames) << run.output.substr(view);  // nearly every frame showed a newer step
  EXPECT_LE(shown, frames) << run.output.substr(view);
  EXPECT_LT(shown, 1000) << run.output.substr(view);
  EXPECT_NE(run.output.find("real time: "), std::string::npos);
  const Image image = ReadPng(png);
  long grey = 0;  // the robot's default colour, shaded: bluish greys brighter than the floor
  for (int y = 0; y < image.height; ++y)
    for (int x = 0; x < image.width; ++x) {
      const auto p = image.Pixel(x, y);
      grey += p[2] > 120 && p[2] >= p[0] && std::abs(int(p[0]) - int(p[1])) < 20;
    }
  EXPECT_GT(grey, 2000);
  std::filesystem::remove(png);
  // A keyboard needs the window.
  const CommandRun keys = Trocar("teleop --robot robots/davinci-classic/psm.yaml --input keyboard --duration 1");
  EXPECT_EQ(keys.exit_code, 1) << keys.output;
  EXPECT_NE(keys.output.find("--view"), std::string::npos) << keys.output;
}

TEST_F(ViewCli, ASceneSavedAndLoadedRendersTheSamePicture) {
  const planners::PlanFile file = planners::ReadPlanFile(Plan());
  std::string motion;
  for (const auto& m : file.plans[0].motions)
    if (m.solved && motion.empty()) motion = " --motion " + m.arm + ":" + std::to_string(m.sample);
  ASSERT_FALSE(motion.empty());
  const std::string common = " --view external --size 400x300 --screenshot ";
  CommandRun run = Trocar("view patients/phantom-default " + Plan() + motion +
                          " --colour heart=0,0,255 --opacity skin=0.1 --hide table --colour background=40,0,0" +
                          common + Out("saved.png") + " --save-scene " + Out("scene.json"));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  // From another folder: the scene file's paths do not depend on where it is opened.
  run = Shell("cd / && " + std::string(TROCAR_BINARY) + " view --scene " + Out("scene.json") + common + Out("loaded.png"));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const Image saved = ReadPng(Out("saved.png"));
  EXPECT_EQ(saved.rgb, ReadPng(Out("loaded.png")).rgb);
  // What the scene holds mattered: the plan's default picture differs.
  run = Trocar("view patients/phantom-default " + Plan() + common + Out("default.png"));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(saved.rgb, ReadPng(Out("default.png")).rgb);
  // A scene file round-trips through its reader.
  const SceneFile scene = ReadSceneFile(Out("scene.json"));
  WriteSceneFile(Out("again.json"), scene);
  EXPECT_EQ(ReadTextFile(Out("again.json")), ReadTextFile(Out("scene.json")));
  EXPECT_FALSE(scene.style.Visible("table"));
  EXPECT_EQ(scene.style.Opacity("skin"), 0.1);
  // The command line's style applies over the scene (it was silently ignored): flat, the skin,
  // ribs and sternum hidden, the heart in magenta, then the heart hidden too; a pose given with a
  // scene is refused (the scene saves its own).
  const std::string over =
      " view --scene " + Out("scene.json") +
      " --flat --hide skin --hide ribs --hide sternum --colour heart=255,0,255";
  run = Shell("cd / && " + std::string(TROCAR_BINARY) + over + common + Out("flat.png"));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  run = Shell("cd / && " + std::string(TROCAR_BINARY) + over + " --hide heart" + common +
              Out("hidden.png"));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_GT(CountRgb(ReadPng(Out("flat.png")), 255, 0, 255), 200)
      << "the heart, flat, in the colour given";
  EXPECT_EQ(CountRgb(ReadPng(Out("hidden.png")), 255, 0, 255), 0) << "--hide heart over the scene";
  run = Trocar("view --scene " + Out("scene.json") + motion + common + Out("posed.png"));
  EXPECT_EQ(run.exit_code, 1) << run.output;
  EXPECT_NE(run.output.find("give no --motion or --robot"), std::string::npos) << run.output;
  // Bad scene files are named, field by field.
  nlohmann::json doc = nlohmann::json::parse(ReadTextFile(Out("scene.json")));
  auto refuse = [&](const nlohmann::json& d, const std::string& named) {
    WriteFileAtomically(Out("bad_scene.json"), d.dump());
    const CommandRun r = Trocar("view --scene " + Out("bad_scene.json") + common + Out("bad_scene.png"));
    EXPECT_EQ(r.exit_code, 1) << named << "\n" << r.output;
    EXPECT_NE(r.output.find(named), std::string::npos) << r.output;
    EXPECT_FALSE(std::filesystem::exists(Out("bad_scene.png")));
  };
  nlohmann::json bad = doc;
  bad["camera"]["view_angle_deg"] = 400;
  refuse(bad, "camera");
  bad = doc;
  bad["style"]["colours"]["heart"] = {2, 0, 0};
  refuse(bad, "style.colours.heart");
  bad = doc;
  bad["q"]["no_such_joint"] = 0;
  refuse(bad, "no_such_joint");
  bad = doc;
  bad["format"] = "something";
  refuse(bad, "not a trocar scene");
  bad = doc;
  bad["plan_index"] = 0;
  refuse(bad, "plan_index");
  // Physical ranges (issue #44 item 1), read in this process: each named by its field.
  auto refused = [&](const nlohmann::json& d, const std::string& named) {
    WriteFileAtomically(Out("bad_scene.json"), d.dump());
    try {
      ReadSceneFile(Out("bad_scene.json"));
      ADD_FAILURE() << "accepted; expected an error naming " << named;
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(named), std::string::npos) << e.what();
    }
  };
  bad = doc;
  bad["camera"]["position"] = {1e300, 0, 0};
  refused(bad, "camera: expected a position and a focal point within 100 m");
  bad = doc;
  {
    const auto& c = doc["camera"];
    for (int k = 0; k < 3; ++k)
      bad["camera"]["view_up"][k] = c["focal_point"][k].get<double>() - c["position"][k].get<double>();
  }
  refused(bad, "camera.view_up: expected an up direction across the view direction");
  for (const double n : {-5.0, 1e300, 1.7}) {
    bad = doc;
    bad["style"]["patient_triangles"] = n;
    refused(bad, "style.patient_triangles: expected a whole number of triangles");
  }
  bad = doc;
  bad["q"][doc["q"].begin().key()] = 1e300;
  refused(bad, "expected a joint value within 1000");
  bad = doc;
  bad["X_WB"][0][3] = 1e308;
  refused(bad, "X_WB: expected a base within 100 m");
  run = Trocar("view patients/phantom-default --scene " + Out("scene.json") + common + Out("bad_scene.png"));
  EXPECT_EQ(run.exit_code, 1) << run.output;
}

TEST_F(ViewCli, TheReportLoadsInABrowserAndShowsThePlansPicturesAndTables) {
  const std::string dir = Out("report");
  nlohmann::json doc = nlohmann::json::parse(ReadTextFile(Plan()));
  const std::string plan = Out("report_plan.json");
  // A baseline beside the plans (the fixture plans without one, to stay quick): plan 2 as if it
  // were the template's.
  ASSERT_GE(doc["plans"].size(), 2u);
  nlohmann::json baseline_plan = doc["plans"][1];
  baseline_plan["rank"] = 0;
  doc["baselines"] = nlohmann::json::array();
  doc["baselines"].push_back({{"kind", "template"},
                              {"name", "test template"},
                              {"placed", true},
                              {"where", {"first port as given", "second port as given"}},
                              {"verdict", {{"suitable", false}, {"summary", "not suitable: as judged"}, {"reasons", {"a reason of its own"}}}},
                              {"plan", baseline_plan}});
  // Plan 1 as if its verification had failed, so that its approval is an override the report
  // must show (the fixture's plan may verify as suitable: the bundled two-arm plan does).
  doc["plans"][0]["verification"]["suitable"] = false;
  WriteFileAtomically(plan, doc.dump());
  CommandRun run = Trocar("signoff " + plan + " --approve --surgeon 'Dr <Ada>' --note 'fine & ready' --override 'for the report'");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  run = Trocar("report " + plan + " --out " + dir + " --plans 2 --flat --colour robot=0,0,255");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const std::string html = ReadTextFile(dir + "/report.html");
  // Self-contained: every picture is embedded, nothing is fetched.
  std::size_t images = 0;
  for (std::size_t at = html.find("src=\""); at != std::string::npos; at = html.find("src=\"", at + 1)) {
    EXPECT_EQ(html.compare(at + 5, 22, "data:image/png;base64,"), 0) << html.substr(at, 60);
    ++images;
  }
  EXPECT_GE(images, 2u);
  for (const std::string plan : {"1", "2"})
    for (const char* picture :
         {"external view", "ports on the chest", "reachability on the targets"})
      EXPECT_NE(html.find("alt=\"plan " + plan + ": " + picture + "\""), std::string::npos)
          << plan << " " << picture;
  EXPECT_EQ(html.find("href="), std::string::npos);
  EXPECT_NE(html.find("Dr &lt;Ada&gt;"), std::string::npos) << "the sign-off, escaped";
  EXPECT_NE(html.find("fine &amp; ready"), std::string::npos);
  EXPECT_NE(html.find("status: <b>approved</b>"), std::string::npos);
  EXPECT_NE(html.find("override: for the report"), std::string::npos);
  // The plans and the baseline in columns (issue #43 item 6): each port in a surgeon's terms, the
  // served samples per target as the verification counted them, one verified verdict per column.
  const auto table_at = html.find("<table class=\"compare\">");
  ASSERT_NE(table_at, std::string::npos);
  const std::string table = html.substr(table_at, html.find("</table>", table_at) - table_at);
  EXPECT_NE(table.find("<th>plan 1</th><th>plan 2</th><th>template: test template</th>"), std::string::npos) << table;
  const std::vector<nlohmann::json> columns = {doc["plans"][0], doc["plans"][1], baseline_plan};
  for (const auto& column : columns) {
    for (const auto& port : column["ports"]) {
      const std::string where = port["anatomy"].get<std::string>();
      EXPECT_NE(where.find("ICS-L"), std::string::npos) << where;
      EXPECT_NE(table.find("<td>" + where + "</td>"), std::string::npos) << where;
    }
  }
  for (const std::string target : {"LAD", "LIMA"}) {
    std::string expected = "<td><b>" + target + " samples served</b></td>";
    for (const auto& column : columns) {
      int of = 0, served = 0;
      for (std::size_t s = 0; s < doc["target_samples"].size(); ++s) {
        if (doc["target_samples"][s]["target"] != target) continue;
        ++of;
        served += column["verification"]["served"][s].get<bool>() ? 1 : 0;
      }
      expected += "<td>" + std::to_string(served) + " of " + std::to_string(of) + "</td>";
    }
    EXPECT_NE(table.find(expected), std::string::npos) << expected << "\n" << table;
  }
  EXPECT_NE(table.find("<td><b>sign-off</b></td><td>approved</td><td>proposed</td><td>(baseline)</td>"), std::string::npos) << table;
  // One verdict that counts, the claimed one labelled beside it; the terms with their units.
  EXPECT_NE(html.find("by verified motions (the verdict that counts)"), std::string::npos);
  EXPECT_NE(html.find("claimed, by the plans' own reach checks"), std::string::npos);
  EXPECT_NE(html.find("<th>unit</th>"), std::string::npos);
  EXPECT_NE(html.find("<td>fraction</td>"), std::string::npos);
  EXPECT_NE(html.find("Baseline, template: test template"), std::string::npos);
  EXPECT_NE(html.find("a reason of its own"), std::string::npos);
  // A real browser shows the pictures (the robot in its flat blue) and the tables (their headers'
  // colour).
  const std::string shot = Out("report.png");
  run = Shell("chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
              "--disable-background-networking --disable-component-update --disable-sync "
              "--hide-scrollbars --user-data-dir=" + Out("chromium") + " --window-size=1280,2400 "
              "--screenshot=" + shot + " file://" + dir + "/report.html");
  ASSERT_TRUE(std::filesystem::exists(shot)) << "chromium (Debian package, scripts/install-deps): " << run.output;
  const Image page = ReadPng(shot);
  EXPECT_GT(CountRgb(page, 0, 0, 255), 2000) << "the plans' pictures";
  EXPECT_GT(CountRgb(page, 31, 119, 180), 2000) << "the tables";
  // The sign-off document (issue #43 item 7): printed by the browser, the summary (verdict,
  // comparison, sign-off block) on the first page and each plan and the baseline on one page of
  // its own: 1 + 2 + 1 pages.
  EXPECT_NE(html.find("<h2>Sign-off</h2>"), std::string::npos);
  EXPECT_NE(html.find("class=\"signature\""), std::string::npos);
  const std::string pdf = Out("report.pdf");
  run = Shell(
      "chromium --headless --no-sandbox --disable-gpu --disable-quic --no-first-run "
      "--disable-background-networking --disable-component-update --disable-sync "
      "--user-data-dir=" +
      Out("chromium") +
      " --no-pdf-header-footer "
      "--generate-pdf-document-outline --print-to-pdf=" +
      pdf + " file://" + dir + "/report.html");
  ASSERT_TRUE(std::filesystem::exists(pdf)) << run.output;
  const std::string bytes = ReadTextFile(pdf);
  int pages = 0;
  for (std::size_t at = bytes.find("/Type /Page"); at != std::string::npos;
       at = bytes.find("/Type /Page", at + 1))
    pages += bytes.compare(at, 12, "/Type /Pages") != 0;
  EXPECT_EQ(pages, 4) << "a summary page, then one page for each of the 2 plans and the baseline";
  // Where each heading lies, from the PDF's outline: the page object its destination names.
  auto page_of = [&](const std::string& title) {
    const auto at = bytes.find("/Title (" + title);
    if (at == std::string::npos) return std::string("missing");
    const auto dest = bytes.find("/Dest [", at);
    return dest == std::string::npos ? std::string("no destination")
                                     : bytes.substr(dest + 7, bytes.find(' ', dest + 7) - dest - 7);
  };
  const std::string first = page_of("Verdict");
  EXPECT_EQ(page_of("Plans compared"), first);
  EXPECT_EQ(page_of("Sign-off)"), first) << "the sign-off block on the summary page";
  const std::set<std::string> plan_pages = {page_of("Plan 1:"), page_of("Plan 2:"),
                                            page_of("Baseline,")};
  EXPECT_EQ(plan_pages.size(), 3u) << "each plan on a page of its own";
  EXPECT_EQ(plan_pages.count(first), 0u) << "no plan on the summary page";
  EXPECT_EQ(plan_pages.count("missing"), 0u);
}

// Issue #43 item 5: each target coloured along its length by how the plan serves it. Plan 1's
// verified motions are set so that every third sample is served, reached by psm1 alone, or by
// no arm; in the targets' view every sample's point shows its own class's colour, and the report
// gives the stretches in a table and a picture.
TEST_F(ViewCli, TheTargetsAreColouredAlongTheirLengthByWhichArmsReachThem) {
  planners::PlanFile file = planners::ReadPlanFile(Plan());
  planners::StoredPlan& plan = file.plans[0];
  ASSERT_TRUE(plan.verified);
  const std::size_t ns = file.samples.size();
  std::vector<planners::ReachClass> want(ns);
  for (std::size_t s = 0; s < ns; ++s)
    want[s] = s % 3 == 0
                  ? planners::ReachClass::kServed
                  : (s % 3 == 1 ? planners::ReachClass::kPartly : planners::ReachClass::kNone);
  for (auto& m : plan.motions) {
    const int c = m.sample % 3;
    m.solved = c == 0 || (c == 1 && m.arm == "psm1");
    if (m.solved) m.failure_pose.resize(0);  // a solved motion has none
    m.outcome = m.solved ? "solved" : "failed";
    m.reason = m.solved ? "" : "set by the test";
  }
  for (std::size_t s = 0; s < ns; ++s) plan.verified_served[s] = s % 3 == 0;
  const std::string path = Out("reach_plan.json");
  planners::WritePlanFile(path, file);

  ViewInputs in;
  in.case_dir = file.case_dir;
  in.plan = path;
  in.flat = true;
  in.reach = true;
  LoadedView view = LoadView(in);
  for (const std::string& g : view.scene->groups())
    view.scene->SetVisible(g, g.rfind("reach:", 0) == 0);
  view.scene->SetBackground(Eigen::Vector3d::Zero());
  const int w = 800, h = 600;
  ViewSpec spec = ViewSpec::Parse("targets");
  const CameraPose camera = ViewCamera(*view.scene, spec, double(w) / h, &plan, nullptr);
  const Image image = Render(*view.scene, {{spec, camera}}, w, h);
  const SceneStyle& style = view.scene->style();
  auto rgb8 = [](const Eigen::Vector3d& c) {
    return std::array<int, 3>{int(std::lround(255 * c.x())), int(std::lround(255 * c.y())),
                              int(std::lround(255 * c.z()))};
  };
  const std::map<planners::ReachClass, std::array<int, 3>> colour = {
      {planners::ReachClass::kServed, rgb8(style.Colour("reach:served"))},
      {planners::ReachClass::kPartly, rgb8(style.Colour("reach:partly"))},
      {planners::ReachClass::kNone, rgb8(style.Colour("reach:none"))}};
  auto near = [](const std::array<std::uint8_t, 3>& p, const std::array<int, 3>& c) {
    return std::abs(p[0] - c[0]) <= 2 && std::abs(p[1] - c[1]) <= 2 && std::abs(p[2] - c[2]) <= 2;
  };
  int shown = 0, right = 0;
  std::map<planners::ReachClass, long> pixels;
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x)
      for (const auto& [c, rgb] : colour) pixels[c] += near(image.Pixel(x, y), rgb);
  for (std::size_t s = 0; s < ns; ++s) {
    Eigen::Vector2d px;
    ASSERT_TRUE(test_projection::Project(camera, w, h, file.samples[s].p_W, &px));
    ASSERT_TRUE(px.x() >= 0 && px.x() < w && px.y() >= 0 && px.y() < h)
        << "sample " << s << " out of the view";
    ++shown;
    // Its class's colour within 2 pixels, and not another class's at the point itself.
    bool found = false;
    for (int dy = -2; dy <= 2 && !found; ++dy)
      for (int dx = -2; dx <= 2 && !found; ++dx) {
        const int x = std::clamp(int(px.x()) + dx, 0, w - 1),
                  y = std::clamp(int(px.y()) + dy, 0, h - 1);
        found = near(image.Pixel(x, y), colour.at(want[s]));
      }
    right += found;
  }
  // (A sample where the other target's tube crosses in front may show that one's colour.)
  EXPECT_GE(right, shown * 9 / 10) << right << " of " << shown << " samples in their colour";
  for (const auto& [c, n] : pixels) EXPECT_GT(n, 30) << "class " << int(c);
  // The report: the table's rows are the stretches, the picture is there.
  const std::string dir = Out("reach_report");
  const CommandRun run = Trocar("report " + path + " --out " + dir + " --plans 1");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const std::string html = ReadTextFile(dir + "/report.html");
  EXPECT_NE(html.find("alt=\"plan 1: reachability on the targets\""), std::string::npos);
  const auto at = html.find("<table class=\"reach\">");
  ASSERT_NE(at, std::string::npos);
  const std::string table = html.substr(at, html.find("</table>", at) - at);
  const planners::Reachability reach =
      planners::TargetReachability(planners::ReadPlanFile(path), 0);
  std::size_t rows = 0;
  for (std::size_t k = table.find("<tr><td>"); k != std::string::npos;
       k = table.find("<tr><td>", k + 1))
    ++rows;
  EXPECT_EQ(rows, reach.stretches.size());
  EXPECT_GE(reach.stretches.size(), ns * 2 / 3)
      << "every third sample alike: a stretch is one sample";
  EXPECT_NE(table.find("no: <span class=\"why\">failed: set by the test</span>"), std::string::npos)
      << table;
}

// The workstation's plan page says each port in a surgeon's terms (as the plan file holds them),
// the terms with their units, and the verdict that counts labelled beside the claimed one.
TEST_F(ViewCli, TheWorkstationsPlanPageSaysThePortsInAnatomicalTermsAndBothVerdicts) {
  const planners::PlanFile file = planners::ReadPlanFile(Plan());
  const nlohmann::json doc = nlohmann::json::parse(ReadTextFile(Plan()));
  for (std::size_t k = 0; k < file.plans.size(); ++k) {
    const std::string page = PlanPageHtml(file, k);
    for (const auto& port : doc["plans"][k]["ports"]) {
      const std::string line = "<li>" + port["arm"].get<std::string>() + ": " + port["anatomy"].get<std::string>() + "</li>";
      EXPECT_NE(page.find(line), std::string::npos) << line << "\n" << page;
    }
    EXPECT_NE(page.find("<td>fraction</td>"), std::string::npos) << page;
    ASSERT_TRUE(doc["verdict"].contains("verified"));
    EXPECT_NE(page.find("Verdict, by verified motions (the one that counts)"), std::string::npos) << page;
    EXPECT_NE(page.find("Verdict claimed by the plans' reach checks"), std::string::npos) << page;
  }
  EXPECT_THROW(PlanPageHtml(file, file.plans.size()), Error);
}

TEST_F(ViewCli, AnArmOfThePlanIsTeleoperatedInItsPatientWithItsCollisionsSaid) {
  // Headless: the plan's psm1 from its nominal pose follows a small circle.
  CommandRun run = Trocar("teleop --plan " + Plan() + " --arm psm1 --input circle --amplitude 0.005 --duration 1.5");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("the nominal pose of plan 1, arm psm1"), std::string::npos) << run.output;
  const auto at = run.output.find("position error:    RMS ");
  ASSERT_NE(at, std::string::npos) << run.output;
  EXPECT_LT(std::stod(run.output.substr(at + 23)), 3.0) << run.output;  // mm, a 5 mm circle
  // In the window: the patient, the cart and each frame's collisions by the plan's rules.
  const std::string png = Out("teleop_plan.png");
  run = Trocar("teleop --plan " + Plan() + " --arm psm1 --view --fps 20 --input circle --amplitude 0.005 "
               "--duration 1.5 --grab " + png);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("frames in collision"), std::string::npos) << run.output;
  EXPECT_GT(ReadPng(png).width, 0);
  run = Trocar("teleop --plan " + Plan() + " --arm psm7 --duration 1");
  EXPECT_EQ(run.exit_code, 1) << run.output;
  EXPECT_NE(run.output.find("no arm 'psm7'"), std::string::npos) << run.output;
  run = Trocar("teleop --plan " + Plan() + " --robot robots/davinci-classic/psm.yaml --duration 1");
  EXPECT_EQ(run.exit_code, 1) << run.output;
}

// Issue #16: a plan's arms driven by devices named in a device file; each instrument's pose goes
// out in the patient's CT frame as 3D Slicer takes it (RAS, millimetres), and force comes back
// as SENSOR messages in newtons, from the arm's nearness to the patient by the plan's rules.
TEST_F(ViewCli, TeleopStreamsThePlansInstrumentsInTheCtFrameAndSendsForceBack) {
  const std::string devices = Out("devices.yaml");
  std::ofstream(devices) << "devices:\n  - {name: left, arm: psm1}\n  - {name: right, arm: psm2}\n";
  const std::string address = "127.0.0.1:" + std::to_string(test::FreePort());
  CommandRun run{-1, ""};
  std::thread trocar([&] {
    run = Trocar("teleop --plan " + Plan() + " --listen " + address + " --devices " + devices +
                 " --duration 2 --wait 20");
  });
  // The left device holds still: psm1 stays at the plan's nominal pose, as does psm2 (its
  // device never comes).
  control::IgtlDeviceClient client("127.0.0.1", std::stoi(address.substr(10)), 20.0);
  for (int i = 0; i < 1500; ++i) {
    ASSERT_TRUE(client.SendPose("left", Eigen::Isometry3d::Identity()));
    client.Received();
    std::this_thread::sleep_for(std::chrono::milliseconds(1));
  }
  client.Received();
  trocar.join();
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("CT frame, RAS mm"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("nearest approach"), std::string::npos) << run.output;
  // Where the instruments are, by the test's own kinematics of the plan's nominal pose.
  ViewInputs in;
  in.case_dir = planners::ReadPlanFile(Plan()).case_dir;
  in.plan = Plan();
  const LoadedView view = LoadView(in);
  Eigen::Isometry3d X_RAS_LPS = Eigen::Isometry3d::Identity();
  X_RAS_LPS.linear() = Eigen::Vector3d(-1, -1, 1).asDiagonal();
  for (const auto& arm : view.plan->arms) {
    Eigen::Isometry3d got;
    ASSERT_TRUE(client.LastTransform(arm.name, &got)) << arm.name << " was not streamed";
    const Eigen::Isometry3d X_WT = kinematics::FramePose(*view.scene->robot_state(), view.robot->GetFrame(arm.tool_frame));
    const Eigen::Isometry3d want = X_RAS_LPS * view.patient->X_WP.inverse() * X_WT;
    EXPECT_LT((got.translation() - want.translation()).norm(), 0.001) << arm.name;  // held within 1 mm
    EXPECT_LT((got.linear() - want.linear()).norm(), 0.01) << arm.name;
  }
  std::vector<double> force;
  std::uint64_t unit = 0;
  ASSERT_TRUE(client.LastSensor("left", &force, &unit)) << "no force message came";
  EXPECT_EQ(force.size(), 3u);
  EXPECT_EQ(unit, control::IgtlNewtonUnit());
  for (double f : force) EXPECT_TRUE(std::isfinite(f));
}

TEST_F(ViewCli, BadInputIsNamedAndNoPictureIsWritten) {
  const std::string png = Out("bad.png");
  WriteFileAtomically(png, "previous");
  auto expect_error = [&](const std::string& arguments, const std::string& named) {
    const CommandRun run = Trocar(arguments + " --screenshot " + png);
    EXPECT_EQ(run.exit_code, 1) << arguments << "\n" << run.output;
    EXPECT_NE(run.output.find(named), std::string::npos) << arguments << "\n" << run.output;
    EXPECT_EQ(ReadTextFile(png), "previous") << arguments;
  };
  const std::string text = ReadTextFile(Plan());
  const std::string truncated = Out("truncated.json");
  WriteFileAtomically(truncated, text.substr(0, text.size() / 2));
  expect_error("view patients/phantom-default " + truncated, "truncated.json: not a plan");
  nlohmann::json doc = nlohmann::json::parse(text);
  doc["plans"][0]["cart"]["X_WB"] = "here";
  WriteFileAtomically(Out("badpose.json"), doc.dump());
  expect_error("view patients/phantom-default " + Out("badpose.json"), "plans[0].cart.X_WB");
  doc = nlohmann::json::parse(text);
  doc["inputs"]["patient_model_hash"] = "fnv1a64:0000000000000000";
  WriteFileAtomically(Out("otherpatient.json"), doc.dump());
  expect_error("view patients/phantom-default " + Out("otherpatient.json"), "another patient model");
  doc = nlohmann::json::parse(text);
  doc["plans"][0]["q_nominal"]["no_such_joint"] = 0.1;
  WriteFileAtomically(Out("badjoint.json"), doc.dump());
  expect_error("view patients/phantom-default " + Out("badjoint.json"), "no_such_joint");
  expect_error("view patients/phantom-default " + Plan() + " --plan 99", "--plan: 99");
  expect_error("view patients/phantom-default " + Plan() + " --motion psm9:0", "psm9");
  expect_error("view patients/phantom-default " + Plan() + " --colour heart=1,2", "heart=1,2");
  expect_error("view patients/phantom-default " + Plan() + " --view sideways", "sideways");
  expect_error("view patients/phantom-default " + Out("missing.json"), "missing.json");
  // A folder that does not exist: named, nothing half-written.
  const CommandRun run = Trocar("view patients/phantom-default --screenshot " + Out("no/such/dir/x.png"));
  EXPECT_EQ(run.exit_code, 1) << run.output;
  EXPECT_NE(run.output.find("x.png"), std::string::npos) << run.output;
  // Without a display: a message, not a crash.
  const CommandRun headless =
      Shell("cd " + SourcePath("") + " && env -u DISPLAY " + TROCAR_BINARY +
          " view patients/phantom-default --screenshot " + png);
  EXPECT_EQ(headless.exit_code, 1) << headless.output;
  EXPECT_NE(headless.output.find("X display"), std::string::npos) << headless.output;
  EXPECT_EQ(ReadTextFile(png), "previous");
}

}  // namespace
}  // namespace trocar::viz
