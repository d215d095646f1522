// The `trocar` command line as a user runs it: exit codes, output and error messages.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <atomic>
#include <thread>
#include <iterator>
#include <map>
#include <array>
#include <thread>
#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <regex>
#include <random>
#include <iomanip>
#include <Eigen/Core>
#include <cstdlib>
#include <sstream>
#include <string>

#include "common/file_util.hpp"
#include "common/plot.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using test::CommandRun;

CommandRun Trocar(const std::string& arguments) {
  return test::RunShell(std::string(TROCAR_BINARY) + " " + arguments);
}

TEST(TrocarRobotInfo, DescribesEveryBundledRobot) {
  for (const char* file :
       {"robots/pa10/pa10.yaml", "robots/pa10/pa10.urdf", "robots/pa10/pa10_instrument.yaml",
        "robots/prismatic-test/prismatic10.yaml", "robots/parallelogram/parallelogram.urdf",
        "robots/davinci-classic/psm.yaml", "robots/davinci-classic/psm_si.yaml",
        "robots/davinci-classic/ecm.yaml", "robots/davinci-classic/ecm_30.yaml",
        "robots/davinci-classic/suj_psm.yaml", "robots/davinci-classic/suj_ecm.yaml"}) {
    const CommandRun run = Trocar("robot info " + test::SourcePath(file));
    EXPECT_EQ(run.exit_code, 0) << file << "\n" << run.output;
    EXPECT_NE(run.output.find("tool pose at q = 0"), std::string::npos) << run.output;
    EXPECT_NE(run.output.find("joints (SI units"), std::string::npos) << run.output;
  }
}

// The meshes a bundled arm wears, per link with its drift and tolerance; a missing appearance
// file is said, not an error.
TEST(TrocarRobotInfo, SaysWhichMeshesTheLinksWearAndHowNearTheyFollow) {
  TROCAR_REQUIRE_SHARED_FILE(test::SharedDataPath("robots/surrol-psm/psm.urdf"));
  const CommandRun run =
      Trocar("robot info " + test::SourcePath("robots/davinci-classic/psm.yaml"));
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("appearance: 13 links wear the meshes of "), std::string::npos)
      << run.output;
  std::smatch m;
  ASSERT_TRUE(std::regex_search(
      run.output, m,
      std::regex("jaw_1_link +wears psm_tool_gripper1_link +drawn within ([0-9.]+) mm "
                 "of its place \\(at most 2.0\\)")))
      << run.output;
  EXPECT_LT(std::stod(m[1].str()), 2.0);
  EXPECT_NE(run.output.find("pitch_top_link"), std::string::npos);
  EXPECT_NE(run.output.find("(at most 10.0)"), std::string::npos) << run.output;
}

TEST(TrocarRobotInfo, PrintsTheDhTableAndTheClosure) {
  const CommandRun pa10 = Trocar("robot info " + test::SourcePath("robots/pa10/pa10.urdf"));
  EXPECT_NE(pa10.output.find("equivalent DH table"), std::string::npos) << pa10.output;
  const CommandRun loop =
      Trocar("robot info " + test::SourcePath("robots/parallelogram/parallelogram.urdf"));
  EXPECT_NE(loop.output.find("closure 'pitch_parallelogram': driver crank_joint"),
            std::string::npos)
      << loop.output;
}

TEST(TrocarRobotFk, PrintsTheSamePoseAsTheLibrary) {
  const std::string file = test::SourcePath("robots/pa10/pa10.yaml");
  const CommandRun run = Trocar("robot fk " + file + " 0.1 -0.5 0.3 1.2 -0.4 -0.3 0.1");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  const auto model = robot::LoadRobot(file);
  robot::RobotState state(model);
  Eigen::VectorXd q(7);
  q << 0.1, -0.5, 0.3, 1.2, -0.4, -0.3, 0.1;
  kinematics::ForwardKinematics(model, q, &state);
  const Eigen::Vector3d p = kinematics::ToolPoseInBase(model, state).translation();
  std::smatch m;
  const std::regex position(R"(position \(m\):\s+(\S+) (\S+) (\S+))");
  ASSERT_TRUE(std::regex_search(run.output, m, position)) << run.output;
  EXPECT_NEAR(std::stod(m[1]), p.x(), 1e-6);
  EXPECT_NEAR(std::stod(m[2]), p.y(), 1e-6);
  EXPECT_NEAR(std::stod(m[3]), p.z(), 1e-6);
}

TEST(TrocarRobotFk, AcceptsDegreesAndExpressions) {
  const std::string file = test::SourcePath("robots/pa10/pa10.yaml");
  const CommandRun degrees = Trocar("robot fk " + file + " --deg 0 -30 0 90 0 0 0");
  const CommandRun radians = Trocar("robot fk " + file + " -- 0 -pi/6 0 pi/2 0 0 0");
  ASSERT_EQ(degrees.exit_code, 0) << degrees.output;
  ASSERT_EQ(radians.exit_code, 0) << radians.output;
  // Same pose; only the echoed q line differs in formatting.
  EXPECT_EQ(degrees.output.substr(degrees.output.find("position")),
            radians.output.substr(radians.output.find("position")));
}

TEST(TrocarRobotFk, WrongCountAndOutOfLimitValuesAreClearErrors) {
  const std::string file = test::SourcePath("robots/pa10/pa10.yaml");
  const CommandRun count = Trocar("robot fk " + file + " 0 0 0");
  EXPECT_EQ(count.exit_code, 1);
  EXPECT_NE(count.output.find("error: robot 'pa10' has 7 active joints, got 3 values"),
            std::string::npos)
      << count.output;
  const CommandRun limits = Trocar("robot fk " + file + " 0 2 0 0 0 0 0");
  EXPECT_EQ(limits.exit_code, 1);
  EXPECT_NE(limits.output.find("joint 'S2' = 2 outside"), std::string::npos) << limits.output;
  const CommandRun nan = Trocar("robot fk " + file + " 0 nan 0 0 0 0 0");
  EXPECT_EQ(nan.exit_code, 1);
  EXPECT_NE(nan.output.find("value 2 ('nan') is not a finite number"), std::string::npos)
      << nan.output;
}

TEST(TrocarRobotFk, AClosureOutOfRangeIsReportedNotCrashed) {
  const CommandRun run =
      Trocar("robot fk " + test::SourcePath("robots/parallelogram/parallelogram.urdf") +
             " 0 1.7 0 --ignore-limits");
  EXPECT_EQ(run.exit_code, 3);
  EXPECT_NE(run.output.find("not reachable: closure 'pitch_parallelogram'"), std::string::npos)
      << run.output;
}

TEST(TrocarRobotInfo, ShowsTheWholeDaVinciCart) {
  const CommandRun run =
      Trocar("robot info " + test::SourcePath("robots/davinci-classic/cart.yaml"));
  EXPECT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("18 active, 16 held"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("psm2_rcm on link"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("closure 'ecm_pitch_parallelogram_2'"), std::string::npos);
}

TEST(TrocarRobotSuj, PlacesAnRcmOrSaysHowFarOffItIs) {
  const std::string cart = test::SourcePath("robots/davinci-classic/cart.yaml");
  const CommandRun ok =
      Trocar("robot suj " + cart + " --frame psm1_rcm --position 0.9 -0.15 1.1 --axis 0.2 0 -1");
  EXPECT_EQ(ok.exit_code, 0) << ok.output;
  EXPECT_NE(ok.output.find("frame 'psm1_rcm' placed (error under 0.01 mm"), std::string::npos)
      << ok.output;
  EXPECT_NE(ok.output.find("psm1_suj_wrist_3"), std::string::npos) << ok.output;
  const CommandRun far = Trocar("robot suj " + cart + " --frame ecm_rcm --position 5 0 1");
  EXPECT_EQ(far.exit_code, 3) << far.output;
  EXPECT_NE(far.output.find("unreachable: frame 'ecm_rcm' stays"), std::string::npos) << far.output;
  const CommandRun bad = Trocar("robot suj " + cart + " --frame psm9_rcm --position 1 0 1");
  EXPECT_EQ(bad.exit_code, 1) << bad.output;
  EXPECT_NE(bad.output.find("has no frame or link 'psm9_rcm'"), std::string::npos) << bad.output;
}

TEST(TrocarTeleop, RunsHeadlessAndRecords) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_teleop";
  std::filesystem::remove_all(dir);
  const CommandRun run =
      Trocar("teleop --robot " + test::SourcePath("robots/davinci-classic/psm.yaml") +
             " --input step --scale 5 --duration 2 --controller dls --record " + dir);
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("scale 5:1"), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("settling time after the step"), std::string::npos) << run.output;
  std::ifstream csv(dir + "/record.csv");
  std::string header;
  std::getline(csv, header);
  EXPECT_EQ(header.rfind("t,xd,yd,zd,qwd,qxd,qyd,qzd,x,y,z,qw,qx,qy,qz,q_outer_yaw", 0), 0u)
      << header;
  int rows = 0;
  for (std::string line; std::getline(csv, line);) ++rows;
  EXPECT_EQ(rows, 2001);
  for (const char* figure : {"tracking.png", "errors.png"}) {
    const Image image = DecodePng(ReadTextFile(dir + "/" + figure));
    EXPECT_EQ(image.width, 960) << figure;
    EXPECT_GT(image.height, 500) << figure;
  }
}

// An output that cannot be written is found before the run, not after it (issue #19).
TEST(TrocarTeleop, ARecordFolderThatCannotTakeTheRecordFailsBeforeTheRun) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_teleop_blocked";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir + "/record.csv");  // a folder where the file goes
  const CommandRun run = Trocar("teleop --robot " + test::SourcePath("robots/pa10/pa10.yaml") +
                                " --input sinusoid --duration 30 --record " + dir);
  EXPECT_EQ(run.exit_code, 1) << run.output;
  EXPECT_NE(run.output.find("record.csv exists and is not a file"), std::string::npos) << run.output;
  EXPECT_EQ(run.output.find("position error"), std::string::npos) << "the run went ahead:\n" << run.output;
}

// A long session keeps a bounded record, thinned uniformly, and says so (issue #19).
TEST(TrocarTeleop, ALongSessionsRecordIsBoundedAndSaysItWasThinned) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_teleop_thinned";
  std::filesystem::remove_all(dir);
  setenv("TROCAR_MAX_RECORDED_SAMPLES", "300", 1);
  const CommandRun run = Trocar("teleop --robot " + test::SourcePath("robots/pa10/pa10.yaml") +
                                " --input sinusoid --duration 2 --controller dls --record " + dir);
  unsetenv("TROCAR_MAX_RECORDED_SAMPLES");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("samples: 2001 ("), std::string::npos) << run.output;
  EXPECT_NE(run.output.find("record thinned to every 8th step"), std::string::npos) << run.output;
  std::ifstream csv(dir + "/record.csv");
  int rows = -1;
  for (std::string line; std::getline(csv, line);) ++rows;
  EXPECT_LE(rows, 300);
  EXPECT_GE(rows, 150);
}

// A random serial arm as a plain URDF (issue #18): 6 or 7 joints, up to two prismatic, random
// link offsets (0.1-0.35 m along, ±0.1 m across), random orientations and axes, revolute ranges
// of ±2.5-3.1 rad, prismatic ±0.25 m, and a flange behind a fixed joint.
std::string RandomArmUrdf(unsigned seed) {
  std::mt19937 rng(seed);
  auto uniform = [&](double a, double b) { return std::uniform_real_distribution<double>(a, b)(rng); };
  const int n = 6 + static_cast<int>(rng() % 2);
  std::vector<bool> prismatic(n, false);
  const int k = static_cast<int>(rng() % 3);
  for (int i = 0; i < k; ++i) prismatic[rng() % n] = true;
  std::ostringstream u;
  u << std::setprecision(6) << "<robot name=\"random" << seed << "\"><link name=\"base\"/>";
  std::string parent = "base";
  for (int i = 0; i < n; ++i) {
    const std::string child = "l" + std::to_string(i + 1);
    Eigen::Vector3d axis(std::normal_distribution<double>()(rng), std::normal_distribution<double>()(rng),
                         std::normal_distribution<double>()(rng));
    axis.normalize();
    u << "<link name=\"" << child << "\"/><joint name=\"j" << i + 1 << "\" type=\""
      << (prismatic[i] ? "prismatic" : "revolute") << "\"><parent link=\"" << parent
      << "\"/><child link=\"" << child << "\"/><origin xyz=\"" << uniform(-0.1, 0.1) << " "
      << uniform(-0.1, 0.1) << " " << uniform(0.1, 0.35) << "\" rpy=\"" << uniform(-M_PI, M_PI)
      << " " << uniform(-M_PI, M_PI) << " " << uniform(-M_PI, M_PI) << "\"/><axis xyz=\""
      << axis.x() << " " << axis.y() << " " << axis.z() << "\"/>";
    if (prismatic[i]) {
      u << "<limit lower=\"-0.25\" upper=\"0.25\" velocity=\"0.5\" effort=\"10\"/>";
    } else {
      u << "<limit lower=\"" << -uniform(2.5, 3.1) << "\" upper=\"" << uniform(2.5, 3.1)
        << "\" velocity=\"2\" effort=\"10\"/>";
    }
    u << "</joint>";
    parent = child;
  }
  u << "<link name=\"flange\"/><joint name=\"jf\" type=\"fixed\"><parent link=\"" << parent
    << "\"/><child link=\"flange\"/><origin xyz=\"0 0 0.08\"/></joint></robot>\n";
  return u.str();
}

double RmsPositionErrorMm(const std::string& output) {
  std::smatch m;
  static const std::regex kRms("position error:\\s+RMS ([0-9.e+-]+) mm");
  return std::regex_search(output, m, kRms) ? std::stod(m[1]) : 1e9;
}

// With default settings and no sidecar, a plain URDF tracks the thesis' sinusoid (issue #18): the
// start is chosen away from limits and singularities and the default controller is dls. Over
// random arms, each tracks to under 0.5 mm RMS, or trocar says before the run that its workspace
// cannot hold the hand's motion (a random arm may simply not reach); most track.
TEST(TrocarTeleop, PlainUrdfsOfRandomArmsTrackWithDefaultSettings) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_random_arms";
  std::filesystem::create_directories(dir);
  int tracked = 0;
  const int robots = 24;
  for (int seed = 0; seed < robots; ++seed) {
    const std::string path = dir + "/arm" + std::to_string(seed) + ".urdf";
    std::ofstream(path) << RandomArmUrdf(static_cast<unsigned>(seed));
    const CommandRun run = Trocar("teleop --robot " + path + " --input sinusoid");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    const double rms = RmsPositionErrorMm(run.output);
    if (rms < 0.5) {
      ++tracked;
    } else {
      EXPECT_NE(run.output.find("the tool follows only"), std::string::npos)
          << "arm " << seed << " tracks to " << rms << " mm without a warning:\n" << run.output;
    }
  }
  std::cout << tracked << " of " << robots << " random arms track to under 0.5 mm RMS\n";
  EXPECT_GE(tracked, robots * 9 / 10);
  // The PA10 as a plain URDF: 38 mm RMS from q = 0 with the old defaults.
  const CommandRun pa10 = Trocar("teleop --robot " + test::SourcePath("robots/pa10/pa10.urdf") +
                                 " --input sinusoid");
  EXPECT_LT(RmsPositionErrorMm(pa10.output), 0.5) << pa10.output;
  EXPECT_NE(pa10.output.find("chosen automatically"), std::string::npos) << pa10.output;
  EXPECT_NE(pa10.output.find("controller dls"), std::string::npos) << pa10.output;
  // An arm with fewer than six joints follows the position by default.
  const CommandRun loop = Trocar("teleop --robot " + test::SourcePath("robots/parallelogram/parallelogram.urdf") +
                                 " --input sinusoid");
  EXPECT_LT(RmsPositionErrorMm(loop.output), 0.5) << loop.output;
  EXPECT_NE(loop.output.find("position only (fewer than 6 joints)"), std::string::npos) << loop.output;
  // A start near a singularity, given by hand, is warned about.
  const CommandRun stretched = Trocar("teleop --robot " + test::SourcePath("robots/pa10/pa10.urdf") +
                                      " --input sinusoid --duration 0.5 --q0 0 0 0 0 0 0 0");
  EXPECT_NE(stretched.output.find("warning: the start configuration is near a singularity"),
            std::string::npos)
      << stretched.output;
}

// Every bundled robot with joints to drive follows the thesis' sinusoid with default settings,
// or says before the run why it cannot: the ECM at its 5 cm home needs 2.5 rad/s of yaw for a 1:1
// sinusoid where its limit is 1 rad/s, and follows it at 3:1. An arm of setup joints only has
// nothing to drive and says so.
TEST(TrocarTeleop, BundledRobotsTrackTheSinusoidOrSayWhyNot) {
  const char* kWarning = "over its velocity limit";
  for (const char* robot : {"robots/pa10/pa10.yaml", "robots/pa10/pa10_instrument.yaml",
                            "robots/davinci-classic/psm.yaml", "robots/davinci-classic/psm_si.yaml",
                            "robots/davinci-classic/cart.yaml", "robots/prismatic-test/prismatic10.yaml"}) {
    const CommandRun run = Trocar(std::string("teleop --robot ") + test::SourcePath(robot) + " --input sinusoid");
    ASSERT_EQ(run.exit_code, 0) << run.output;
    EXPECT_LT(RmsPositionErrorMm(run.output), 0.5) << robot << "\n" << run.output;
    EXPECT_EQ(run.output.find(kWarning), std::string::npos) << robot << "\n" << run.output;
  }
  for (const char* ecm : {"robots/davinci-classic/ecm.yaml", "robots/davinci-classic/ecm_30.yaml"}) {
    const CommandRun fast = Trocar(std::string("teleop --robot ") + test::SourcePath(ecm) + " --input sinusoid");
    ASSERT_EQ(fast.exit_code, 0) << fast.output;
    EXPECT_GT(RmsPositionErrorMm(fast.output), 5.0) << fast.output;
    EXPECT_NE(fast.output.find("joint 'outer_yaw' would need"), std::string::npos) << fast.output;
    EXPECT_NE(fast.output.find(kWarning), std::string::npos) << fast.output;
    const CommandRun scaled =
        Trocar(std::string("teleop --robot ") + test::SourcePath(ecm) + " --input sinusoid --scale 3");
    EXPECT_LT(RmsPositionErrorMm(scaled.output), 0.5) << scaled.output;
    EXPECT_EQ(scaled.output.find(kWarning), std::string::npos) << scaled.output;
  }
  const CommandRun suj = Trocar("teleop --robot " + test::SourcePath("robots/davinci-classic/suj_psm.yaml") +
                                " --input sinusoid");
  EXPECT_EQ(suj.exit_code, 1) << suj.output;
  EXPECT_NE(suj.output.find("has no active joints to drive (its 6 movable joints are held setup joints"),
            std::string::npos)
      << suj.output;
}

// Jacobian transpose on a robot that gives no gains: tuned on first use (22 mm RMS untuned on the
// PA10), saved in the overlay beside the robot, read back next time; the URDF is untouched.
TEST(TrocarTeleop, JacobianTransposeGainsAreTunedOnFirstUseIntoAnOverlay) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_jt_first_use";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::string urdf = dir + "/arm.urdf";
  std::filesystem::copy_file(test::SourcePath("robots/pa10/pa10.urdf"), urdf);
  const std::string original = ReadTextFile(urdf);
  const CommandRun first = Trocar("teleop --robot " + urdf + " --controller jt --input sinusoid");
  ASSERT_EQ(first.exit_code, 0) << first.output;
  EXPECT_NE(first.output.find("jt gains tuned on first use"), std::string::npos) << first.output;
  EXPECT_NE(first.output.find("saved to " + dir + "/arm.gains.yaml"), std::string::npos) << first.output;
  EXPECT_LT(RmsPositionErrorMm(first.output), 0.5) << first.output;
  EXPECT_EQ(ReadTextFile(urdf), original);
  const CommandRun second = Trocar("teleop --robot " + urdf + " --controller jt --input sinusoid");
  EXPECT_EQ(second.output.find("tuned on first use"), std::string::npos) << second.output;
  EXPECT_EQ(RmsPositionErrorMm(second.output), RmsPositionErrorMm(first.output));
}

TEST(TrocarTeleop, BadInputsAreClearErrors) {
  const std::string robot = test::SourcePath("robots/pa10/pa10.yaml");
  const CommandRun unknown = Trocar("teleop --robot " + robot + " --input zigzag");
  EXPECT_EQ(unknown.exit_code, 1);
  EXPECT_NE(unknown.output.find("unknown scripted input 'zigzag'"), std::string::npos)
      << unknown.output;
  const std::string csv = ::testing::TempDir() + "/trocar_cli_bad_device.csv";
  std::ofstream(csv) << "t,x,y,z,qw,qx,qy,qz\n0,0,0,0,1,0,0,0\n0.1,0,0,0,1,0,zero,0\n";
  const CommandRun bad = Trocar("teleop --robot " + robot + " --input " + csv);
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.output.find(csv + ":3: column 7 ('qy'): 'zero' is not a number"), std::string::npos)
      << bad.output;
  const CommandRun scale = Trocar("teleop --robot " + robot + " --scale -2 --duration 0.1");
  EXPECT_EQ(scale.exit_code, 1);
  EXPECT_NE(scale.output.find("scale -2 must be a positive number"), std::string::npos)
      << scale.output;
}

TEST(TrocarPhantom, WritesACaseAPersonCanOpen) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_phantom";
  std::filesystem::remove_all(dir);
  const CommandRun run = Trocar("phantom --out " + dir + " --seed 3 --voxel 0.004");
  ASSERT_EQ(run.exit_code, 0) << run.output;
  EXPECT_NE(run.output.find("18 ribs, 16 intercostal spaces"), std::string::npos) << run.output;
  for (const char* file : {"ct.nrrd", "patient.yaml", "truth.json", "markups/LAD.mrk.json",
                           "markups/LIMA.mrk.json", "markups/intercostal_left.mrk.json"}) {
    EXPECT_TRUE(IsRegularFile(dir + "/" + file)) << file;
  }
  const Image preview = DecodePng(ReadTextFile(dir + "/preview.png"));
  EXPECT_GT(preview.width, 100);
  const CommandRun bad = Trocar("phantom --out " + dir + " --body-width 3 --force");
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.output.find("phantom: body_width = 3 is outside"), std::string::npos) << bad.output;
}

// `phantom --out` onto a case someone edited used to overwrite its patient.yaml (issue #19).
TEST(TrocarPhantom, RefusesToOverwriteACaseUnlessForced) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_phantom_again";
  std::filesystem::remove_all(dir);
  ASSERT_EQ(Trocar("phantom --out " + dir + " --seed 2 --voxel 0.004").exit_code, 0);
  { std::ofstream(dir + "/patient.yaml", std::ios::app) << "# edited by hand\n"; }
  const std::string edited = ReadTextFile(dir + "/patient.yaml");
  const CommandRun again = Trocar("phantom --out " + dir + " --seed 3 --voxel 0.004");
  EXPECT_EQ(again.exit_code, 1) << again.output;
  EXPECT_NE(again.output.find("already holds a case"), std::string::npos) << again.output;
  EXPECT_NE(again.output.find("--force"), std::string::npos) << again.output;
  EXPECT_EQ(ReadTextFile(dir + "/patient.yaml"), edited);
  const CommandRun forced = Trocar("phantom --out " + dir + " --seed 3 --voxel 0.004 --force");
  EXPECT_EQ(forced.exit_code, 0) << forced.output;
  EXPECT_NE(ReadTextFile(dir + "/patient.yaml").find("seed 3"), std::string::npos);
}

// Running out of memory is a message saying so and naming the command, not "internal error".
TEST(TrocarPhantom, OutOfMemoryIsAClearError) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_phantom_oom";
  std::filesystem::remove_all(dir);
  const CommandRun run = test::RunShell("bash -c 'ulimit -v 500000; " + std::string(TROCAR_BINARY) +
                                         " phantom --out " + dir + " --voxel 0.0007'");
  const std::string& output = run.output;
  EXPECT_EQ(run.exit_code, 1) << output;
  EXPECT_NE(output.find("error: out of memory running 'trocar phantom --out"), std::string::npos) << output;
  EXPECT_EQ(output.find("internal error"), std::string::npos) << output;
}

// A plan whose fields have the wrong type was "internal error" (exit 2): now a malformed plan
// named by its file (exit 1) (issue #19).
TEST(TrocarCheck, APlanWithFieldsOfTheWrongTypeIsAClearError) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_bad_plan";
  std::filesystem::create_directories(dir);
  for (const char* text : {R"({"format": "trocar-plan", "version": "2"})", R"({"format": 5})",
                           R"({"format": "trocar-plan", "version": 2, "inputs": [1]})"}) {
    const std::string path = dir + "/plan.json";
    std::ofstream(path) << text;
    const CommandRun run = Trocar("check --plan " + path);
    EXPECT_EQ(run.exit_code, 1) << text << "\n" << run.output;
    EXPECT_NE(run.output.find(path), std::string::npos) << run.output;
    EXPECT_EQ(run.output.find("internal error"), std::string::npos) << run.output;
  }
}

TEST(TrocarImport, BuildsThenLoadsThePhantomCaseFromItsCache) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_import";
  std::filesystem::remove_all(dir);
  ASSERT_EQ(Trocar("phantom --out " + dir + " --seed 2 --voxel 0.004").exit_code, 0);
  const CommandRun cold = Trocar("import " + dir);
  ASSERT_EQ(cold.exit_code, 0) << cold.output;
  for (const char* line : {"patient phantom-seed-2\n", "    heart ", "    ribs ", "LAD: 25 points",
                           "normals from file", "port candidates: 8 (markups:",
                           "left side up 25.0 deg", "timings (s): load CT"}) {
    EXPECT_NE(cold.output.find(line), std::string::npos) << line << "\n" << cold.output;
  }
  EXPECT_EQ(cold.output.find("(from cache)"), std::string::npos);
  const CommandRun warm = Trocar("import " + dir);
  EXPECT_NE(warm.output.find("patient phantom-seed-2 (from cache)"), std::string::npos)
      << warm.output;
  EXPECT_NE(warm.output.find("load cache"), std::string::npos) << warm.output;
  // Orientation checked from the anatomy, and said.
  EXPECT_NE(cold.output.find("check: orientation: spine"), std::string::npos) << cold.output;
  // No port candidates (none annotated, no side asked for spaces): non-zero, with the reason.
  std::ofstream(dir + "/patient.yaml", std::ios::trunc)
      << "name: none\nct: ct.nrrd\nunits: hounsfield\nintercostal: {left: false}\n";
  const CommandRun none = Trocar("import " + dir);
  EXPECT_EQ(none.exit_code, 1) << none.output;
  EXPECT_NE(none.output.find("no port candidates: no intercostal space was found"), std::string::npos)
      << none.output;
  const CommandRun missing = Trocar("import " + dir + "/nowhere");
  EXPECT_EQ(missing.exit_code, 1);
  EXPECT_NE(missing.output.find("nowhere: no patient.yaml"), std::string::npos) << missing.output;
}

TEST(TrocarImport, ADicomSeriesCaseImportsAndAnyChangedSliceRebuilds) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_import_dicom";
  std::filesystem::remove_all(dir);
  const CommandRun phantom = Trocar("phantom --out " + dir + " --seed 2 --voxel 0.004 --dicom");
  ASSERT_EQ(phantom.exit_code, 0) << phantom.output;
  EXPECT_NE(phantom.output.find("/ct/ (DICOM series, "), std::string::npos) << phantom.output;
  const CommandRun cold = Trocar("import " + dir);
  ASSERT_EQ(cold.exit_code, 0) << cold.output;
  for (const char* line :
       {"patient phantom-seed-2\n", "    heart ", "LAD: 25 points", "port candidates: 8"}) {
    EXPECT_NE(cold.output.find(line), std::string::npos) << line << "\n" << cold.output;
  }
  EXPECT_NE(Trocar("import " + dir).output.find("(from cache)"), std::string::npos);
  // One voxel of one slice changes: the model is rebuilt.
  const std::string slice = dir + "/ct/slice_0010.dcm";
  std::string bytes = ReadTextFile(slice);
  bytes[bytes.size() - 100] = static_cast<char>(bytes[bytes.size() - 100] ^ 1);
  WriteFileAtomically(slice, bytes);
  const CommandRun changed = Trocar("import " + dir);
  ASSERT_EQ(changed.exit_code, 0) << changed.output;
  EXPECT_EQ(changed.output.find("(from cache)"), std::string::npos) << changed.output;
}

TEST(TrocarCheck, PlacesTheCartAtAPatientAndListsCollisionsAndClearances) {
  const std::string dir = ::testing::TempDir() + "/trocar_cli_check";
  std::filesystem::remove_all(dir);
  ASSERT_EQ(Trocar("phantom --out " + dir + " --seed 2 --voxel 0.004").exit_code, 0);
  const CommandRun run = Trocar("check --patient " + dir);
  // The default cart placement on this phantom collides (the suite's plan tests find free ones):
  // the verdict must say so, and agree with the pairs and the clearances it lists, so that a
  // colliding placement can never pass as success.
  EXPECT_EQ(run.exit_code, 3) << run.output;
  std::smatch pairs;
  ASSERT_TRUE(std::regex_search(run.output, pairs, std::regex("IN COLLISION: ([0-9]+) pairs")))
      << run.output;
  int listed = 0;
  for (const char* cls : {"\n  arm-arm  ", "\n  arm-patient  ", "\n  instrument-patient ",
                          "\n  arm-table  ", "\n  self  "}) {
    for (std::size_t at = run.output.find(cls); at != std::string::npos &&
                                                at < run.output.find("clearances (m):");
         at = run.output.find(cls, at + 1)) {
      ++listed;
    }
  }
  EXPECT_EQ(listed, std::stoi(pairs[1])) << run.output;
  EXPECT_NE(run.output.find("0.0000  "), std::string::npos) << "a collision with no zero clearance";
  for (const char* line :
       {"robot davinci_classic_cart: 51 collision bodies", "3 arms, 3 ports (radius 15 mm)",
        "port psm1_rcm at", "instruments aimed at LAD", "clearances (m):", "arm-table"}) {
    EXPECT_NE(run.output.find(line), std::string::npos) << line << "\n" << run.output;
  }
  EXPECT_NE(run.output.find(run.exit_code == 3 ? "IN COLLISION" : "collision-free"),
            std::string::npos)
      << run.output;
  // A robot alone, at its neutral configuration: free, and no pair listed.
  const CommandRun alone =
      Trocar("check --robot " + test::SourcePath("robots/davinci-classic/psm.yaml"));
  EXPECT_EQ(alone.exit_code, 0) << alone.output;
  EXPECT_NE(alone.output.find("collision-free"), std::string::npos) << alone.output;
  EXPECT_EQ(alone.output.find("IN COLLISION"), std::string::npos) << alone.output;
  const CommandRun bad = Trocar("check --patient " + dir + " --port psm1_rcm=0.1,0.2");
  EXPECT_EQ(bad.exit_code, 1);
  EXPECT_NE(bad.output.find("--port psm1_rcm: expected x,y,z"), std::string::npos) << bad.output;
  const CommandRun bad_base = Trocar("check --patient " + dir + " --base 0 nan 90");
  EXPECT_EQ(bad_base.exit_code, 1) << bad_base.output;
  EXPECT_NE(bad_base.output.find("--base"), std::string::npos) << bad_base.output;
  const CommandRun bad_q = Trocar("check --q 1 2");
  EXPECT_EQ(bad_q.exit_code, 1);
  EXPECT_NE(bad_q.output.find("has 18 active joints, got 2 values"), std::string::npos)
      << bad_q.output;
}

TEST(TrocarRobotInfo, MissingFileIsNamed) {
  const CommandRun run = Trocar("robot info /no/such/robot.urdf");
  EXPECT_EQ(run.exit_code, 1);
  EXPECT_NE(run.output.find("error: /no/such/robot.urdf: robot description not found"),
            std::string::npos)
      << run.output;
}

// trocar plan writes a plan whose every claim trocar check --plan confirms; a plan whose cart was
// moved after the fact is caught; bad options are refused before any work.
// On a terminal (a pseudo-terminal from util-linux's `script`), the long commands show their
// stage, the share done and the time left on one line redrawn in place, cleared before the
// results (issue #43 item 11): plan through the import, the search (its evaluations counted) and
// the verified motions; verify through each plan's motions; import through its stages.
TEST(TrocarPlan, OnATerminalTheLongCommandsShowTheirProgress) {
  const std::string out = ::testing::TempDir() + "trocar_plan_progress";
  std::filesystem::remove_all(out);
  auto on_terminal = [](const std::string& arguments) {
    return test::RunShell("script -qec '" + std::string(TROCAR_BINARY) + " " + arguments + "' /dev/null");
  };
  CommandRun plan = on_terminal("plan --no-remedies " + test::SourcePath("patients/phantom-default") + " --out " + out +
                                " --arms psm1 psm2 --evaluations 80 --starts 2 --polish-evaluations 10"
                                " --top 1 --motion-time 0.3 --baseline none");
  ASSERT_TRUE(plan.exit_code == 0 || plan.exit_code == 4) << plan.output;
  EXPECT_NE(plan.output.find("\rimporting: "), std::string::npos) << plan.output;
  EXPECT_NE(plan.output.find(" % global direct-l: "), std::string::npos) << plan.output;
  EXPECT_NE(plan.output.find(" of 80 evaluations"), std::string::npos) << plan.output;
  EXPECT_NE(plan.output.find(" % verifying motions: plan 1, "), std::string::npos) << plan.output;
  EXPECT_NE(plan.output.find(" left"), std::string::npos) << plan.output;
  // Cleared before the results: the verdict starts its own line.
  EXPECT_NE(plan.output.find("\r\x1b[K"), std::string::npos) << plan.output;
  const auto verdict = plan.output.find("verdict: ");
  ASSERT_NE(verdict, std::string::npos);
  EXPECT_EQ(plan.output[verdict - 1], '\n') << plan.output.substr(verdict - 40, 60);
  CommandRun verify = on_terminal("verify " + out + "/plan.json --motion-time 0.3");
  ASSERT_TRUE(verify.exit_code == 0 || verify.exit_code == 4) << verify.output;
  EXPECT_NE(verify.output.find(" % verifying motions: plan 1 of 1, "), std::string::npos) << verify.output;
  CommandRun import = on_terminal("import " + test::SourcePath("patients/phantom-default"));
  EXPECT_EQ(import.exit_code, 0) << import.output;
  EXPECT_NE(import.output.find("\rimporting: "), std::string::npos) << import.output;
  // --quiet: nothing drawn.
  CommandRun quiet = on_terminal("verify " + out + "/plan.json --motion-time 0.3 --quiet");
  EXPECT_EQ(quiet.output.find(" % verifying motions"), std::string::npos) << quiet.output;
}

TEST(TrocarPlan, WritesAPlanThatCheckConfirmsAndCatchesATamperedOne) {
  const std::string out = ::testing::TempDir() + "trocar_plan_cli";
  std::filesystem::remove_all(out);
  // Planned as a user does, from the checkout with the case's relative path; the plan is then
  // checked from other working directories (it names its inputs by absolute paths).
  const CommandRun plan = test::RunShell(
      "cd " + test::SourcePath("") + " && " + TROCAR_BINARY + " plan patients/phantom-default --out " +
      out + " --evaluations 120 --starts 2 --polish-evaluations 10 --top 2 --seed 3");
  ASSERT_TRUE(plan.exit_code == 0 || plan.exit_code == 4) << plan.output;
  EXPECT_NE(plan.output.find("verdict: "), std::string::npos) << plan.output;
  EXPECT_NE(plan.output.find("coverage"), std::string::npos) << plan.output;
  // The verdict's unserved stretches each say what would reach them, or that nothing near does
  // (issue #43 item 4; the other plan tests skip it with --no-remedies).
  if (plan.exit_code == 4) {
    EXPECT_TRUE(plan.output.find("(the plan would serve ") != std::string::npos ||
                plan.output.find("no port one space up or down") != std::string::npos)
        << plan.output;
  }
  // Not on a terminal (a pipe): no progress line in the output (issue #43 item 11).
  EXPECT_EQ(plan.output.find('\r'), std::string::npos);
  EXPECT_EQ(plan.output.find("\x1b[K"), std::string::npos);
  ASSERT_TRUE(IsRegularFile(out + "/plan.json"));
  ASSERT_TRUE(IsRegularFile(out + "/ports.mrk.json"));
  const CommandRun check = Trocar("check --plan " + out + "/plan.json");
  EXPECT_EQ(check.exit_code, 0) << check.output;
  EXPECT_NE(check.output.find("all hold"), std::string::npos) << check.output;
  const CommandRun from_root =
      test::RunShell("cd / && " + std::string(TROCAR_BINARY) + " check --plan " + out + "/plan.json");
  EXPECT_EQ(from_root.exit_code, 0) << from_root.output;
  // Beside the optimised plans, the TECAB template placed on this patient, scored and verified
  // as they are (issue #41 item 3).
  {
    const nlohmann::json doc = nlohmann::json::parse(ReadTextFile(out + "/plan.json"));
    ASSERT_EQ(doc.at("baselines").size(), 1u);
    const auto& b = doc.at("baselines")[0];
    EXPECT_EQ(b.at("kind"), "template");
    ASSERT_TRUE(b.at("placed").get<bool>()) << b.dump();
    EXPECT_EQ(b.at("plan").at("ports").size(), 3u);
    EXPECT_TRUE(b.at("plan").contains("verification"));
    EXPECT_TRUE(b.at("verdict").contains("verified"));
    // Its unserved stretches are said without what would reach them: the optimised plans beside
    // it are that answer (docs/decisions.md, "The baseline's verdict without remedies").
    // The template serves no sample on this case: it has stretches to name.
    ASSERT_FALSE(b.at("verdict").at("reasons").empty()) << b.at("verdict").dump();
    for (const auto& r : b.at("verdict").at("reasons")) {
      EXPECT_EQ(r.get<std::string>().find("(the plan would serve "), std::string::npos) << r;
      EXPECT_EQ(r.get<std::string>().find("no port one space up or down"), std::string::npos) << r;
    }
    EXPECT_NE(plan.output.find("plan 1 against the template"), std::string::npos) << plan.output;
    // The anatomical selection criteria beside the verdict, with their comparison.
    ASSERT_EQ(doc.at("selection_criteria").at("criteria").size(), 4u);
    EXPECT_FALSE(doc.at("selection_criteria").at("comparison").get<std::string>().empty());
    EXPECT_NE(plan.output.find("anatomical criteria"), std::string::npos) << plan.output;
  }

  // Move plan 1's cart 20 cm in the file (its pose and its x alike): the RCMs leave their pivots.
  {
    nlohmann::json moved = nlohmann::json::parse(ReadTextFile(out + "/plan.json"));
    auto& cart = moved["plans"][0]["cart"];
    cart["x"] = cart["x"].get<double>() + 0.2;
    cart["X_WB"][0][3] = cart["X_WB"][0][3].get<double>() + 0.2;
    WriteFileAtomically(out + "/tampered.json", moved.dump(1));
    const CommandRun tampered = Trocar("check --plan " + out + "/tampered.json");
    EXPECT_EQ(tampered.exit_code, 3) << tampered.output;
    EXPECT_NE(tampered.output.find("from its pivot"), std::string::npos) << tampered.output;
    // The baseline's cart's x alone moved: two poses that disagree, refused by the reader naming
    // the field.
    moved = nlohmann::json::parse(ReadTextFile(out + "/plan.json"));
    auto& base = moved["baselines"][0]["plan"]["cart"];
    base["x"] = base["x"].get<double>() + 0.2;
    WriteFileAtomically(out + "/tampered_baseline.json", moved.dump(1));
    const CommandRun refused = Trocar("check --plan " + out + "/tampered_baseline.json");
    EXPECT_EQ(refused.exit_code, 1) << refused.output;
    EXPECT_NE(refused.output.find("baselines[0].plan.cart"), std::string::npos) << refused.output;
  }

  // The endoscope's view of a sample is re-checked from the joints the plan records for it (its
  // docking pose, or the scope moved to look at the sample): a scope pitched 1.2 rad (69 deg,
  // beyond the 35-deg half field of view from any sample it saw) after the fact no longer sees
  // it; a sample's joints naming a setup joint (not an active one)
  // are refused naming the field.
  {
    nlohmann::json turned = nlohmann::json::parse(ReadTextFile(out + "/plan.json"));
    nlohmann::json* seen = nullptr;
    for (auto& r : turned["plans"][0]["samples"])
      if (r["arm"] == "ecm" && r["reached"].get<bool>() && !seen) seen = &r;
    ASSERT_NE(seen, nullptr) << "plan 1's scope sees no sample";
    // Toward the limit with room for the turn (the ECM's outer pitch: -0.768..1.134 rad).
    const double pitch = (*seen)["q"]["ecm_outer_pitch"].get<double>();
    (*seen)["q"]["ecm_outer_pitch"] = pitch > 0.2 ? pitch - 1.2 : pitch + 1.2;
    WriteFileAtomically(out + "/turned_scope.json", turned.dump(1));
    const CommandRun check_turned = Trocar("check --plan " + out + "/turned_scope.json");
    EXPECT_EQ(check_turned.exit_code, 3) << check_turned.output;
    EXPECT_NE(check_turned.output.find("ecm at sample " + std::to_string((*seen)["sample"].get<int>())),
              std::string::npos) << check_turned.output;
    (*seen)["q"]["ecm_suj_column"] = 0.1;
    WriteFileAtomically(out + "/held_joint.json", turned.dump(1));
    const CommandRun check_held = Trocar("check --plan " + out + "/held_joint.json");
    EXPECT_EQ(check_held.exit_code, 1) << check_held.output;
    EXPECT_NE(check_held.output.find("plans[].samples[].q names 'ecm_suj_column'"), std::string::npos)
        << check_held.output;
  }

  // An arm's tool frame the robot does not have (the cannula's track is found from it): a bad
  // input naming the file and the field, not the robot's bare error.
  nlohmann::json doc = nlohmann::json::parse(ReadTextFile(out + "/plan.json"));
  doc["robot"]["arms"][0]["tool_frame"] = "no_such_frame";
  WriteFileAtomically(out + "/foreign_tool.json", doc.dump(1));
  const CommandRun foreign = Trocar("check --plan " + out + "/foreign_tool.json");
  EXPECT_EQ(foreign.exit_code, 1) << foreign.output;
  EXPECT_NE(foreign.output.find("foreign_tool.json: robot.arms[0].tool_frame"), std::string::npos)
      << foreign.output;
}

// Whatever the planner writes, `trocar check --plan` (none of the optimiser's code) confirms:
// on phantoms of other seeds and sizes (ribs, heart, width and depth jittered), each planned with
// a small budget. A planner whose claims drift from the robot model, the joint limits or the
// collision checker fails here. The phantoms' CTs at 3 mm voxels: the claims do not depend on the
// scan's resolution, and their import takes 3 s instead of 8 (most of it the surfaces).
// Issue #41's must-hold, for the two instruments of the bundled default (the three arms are not
// there yet: docs/decisions.md, stop 65): verdict suitable, by the claims and by the verified
// motions; the best plan verifies at least 90 % of its (instrument, sample) motions; every target
// has at least 80 % of its samples served; the TECAB template beside it does no better on verified
// coverage or score; and `check --plan` confirms the file. (Release only: "BundledDefault".)
TEST(TrocarPlan, TheBundledDefaultsTwoInstrumentsAreSuitableAndBeatTheTemplate) {
  const std::string out = ::testing::TempDir() + "trocar_plan_suitable";
  std::filesystem::remove_all(out);
  const CommandRun plan =
      test::RunShell("cd " + test::SourcePath("") + " && " + TROCAR_BINARY +
                     " plan patients/phantom-default --arms psm1 psm2 --out " + out);
  ASSERT_EQ(plan.exit_code, 0) << plan.output;
  EXPECT_NE(plan.output.find("verdict: suitable"), std::string::npos) << plan.output;
  EXPECT_NE(plan.output.find("verified verdict: suitable"), std::string::npos) << plan.output;
  const nlohmann::json doc = nlohmann::json::parse(ReadTextFile(out + "/plan.json"));
  EXPECT_TRUE(doc.at("verdict").at("suitable").get<bool>());
  const auto& best = doc.at("plans").at(0);
  const auto& v = best.at("verification");
  EXPECT_TRUE(v.at("suitable").get<bool>());
  EXPECT_GE(v.at("verified_coverage").get<double>(), 0.9);
  std::map<std::string, std::pair<int, int>> per_target;  // served, samples
  const auto& samples = doc.at("target_samples");
  ASSERT_EQ(samples.size(), v.at("served").size());
  for (std::size_t i = 0; i < samples.size(); ++i) {
    auto& [served, all] = per_target[samples[i].at("target").get<std::string>()];
    served += v.at("served")[i].get<bool>() ? 1 : 0;
    ++all;
  }
  ASSERT_EQ(per_target.size(), 2u);  // the LAD and the LIMA
  for (const auto& [target, counts] : per_target)
    EXPECT_GE(counts.first, 0.8 * counts.second)
        << target << ": " << counts.first << " of " << counts.second;
  ASSERT_EQ(doc.at("baselines").size(), 1u);
  const auto& t = doc.at("baselines")[0].at("plan");
  EXPECT_LE(t.at("verification").at("verified_coverage").get<double>(),
            v.at("verified_coverage").get<double>());
  EXPECT_LE(t.at("score").get<double>(), best.at("score").get<double>());
  const CommandRun check = Trocar("check --plan " + out + "/plan.json");
  EXPECT_EQ(check.exit_code, 0) << check.output;
}

TEST(TrocarPlan, CheckConfirmsEveryPlanOnPhantomsOfManySeedsAndSizes) {
  struct Size {
    unsigned seed;
    double width, depth, length;
    int ribs;
  };
  for (const Size& size : {Size{2, 0.30, 0.22, 0.34, 9}, Size{3, 0.36, 0.25, 0.38, 10},
                           Size{4, 0.33, 0.23, 0.32, 8}}) {
    const std::string dir =
        ::testing::TempDir() + "trocar_plan_phantom_" + std::to_string(size.seed);
    std::filesystem::remove_all(dir);
    std::filesystem::create_directories(dir);
    std::ostringstream yaml;
    yaml << "name: phantom-" << size.seed << "\nct: ct.nrrd\n"
         << "phantom: {seed: " << size.seed << ", body_width: " << size.width
         << ", body_depth: " << size.depth << ", length: " << size.length
         << ", ribs_per_side: " << size.ribs << ", voxel_size: 0.003}\n"
         << "units: hounsfield\npose: {left_side_up: 25 deg}\ntargets:\n"
         << "  - {name: LAD, markups: markups/LAD.mrk.json, surface: heart}\n"
         << "  - {name: LIMA, markups: markups/LIMA.mrk.json, surface: skin, facing: inward}\n"
         << "intercostal: {left: true}\n";
    WriteFileAtomically(dir + "/patient.yaml", yaml.str());
    const CommandRun plan = Trocar("plan --no-remedies " + dir + " --out " + dir + "/out --evaluations 120 " +
                                   "--starts 2 --polish-evaluations 10 --top 2 --samples 4 " +
                                   "--seed " + std::to_string(size.seed));
    ASSERT_TRUE(plan.exit_code == 0 || plan.exit_code == 4) << plan.output;
    const CommandRun check = Trocar("check --plan " + dir + "/out/plan.json");
    EXPECT_EQ(check.exit_code, 0) << "seed " << size.seed << "\n" << check.output;
    EXPECT_NE(check.output.find("all hold"), std::string::npos) << check.output;
  }
}

// A generic robot: the PA10 holding an instrument through one port with a software RCM (no RCM
// frame: its shaft is kept through the pivot by its own joints). One arm, one port, samples
// reached, and every claim confirmed by check. One plan, and half a second a motion query: the
// PA10's motions that OMPL does not find time out (at the default 2 s, 25 of the test's 30 s).
TEST(TrocarPlan, APa10WithASoftwareRcmGetsAOnePortPlanThatCheckConfirms) {
  const std::string out = ::testing::TempDir() + "trocar_plan_pa10";
  std::filesystem::remove_all(out);
  const CommandRun plan =
      Trocar("plan --no-remedies " + test::SourcePath("patients/phantom-default") + " --out " + out +
             " --robot " + test::SourcePath("robots/pa10/pa10_instrument.yaml") +
             " --evaluations 300 --starts 2 --polish-evaluations 20 --top 1 --motion-time 0.5");
  ASSERT_TRUE(plan.exit_code == 0 || plan.exit_code == 4) << plan.output;
  const std::string text = ReadTextFile(out + "/plan.json");
  EXPECT_NE(text.find("\"name\": \"pa10_instrument\""), std::string::npos);
  EXPECT_NE(text.find("\"rcm_frame\": \"\""), std::string::npos);             // a software RCM
  EXPECT_FALSE(std::regex_search(text, std::regex("\"rcm_frame\": \"[^\"]")));  // and no other arm
  EXPECT_NE(text.find("\"reached\": true"), std::string::npos);   // it reaches something
  const CommandRun check = Trocar("check --plan " + out + "/plan.json");
  EXPECT_EQ(check.exit_code, 0) << check.output;
  EXPECT_NE(check.output.find("all hold"), std::string::npos) << check.output;
}

// The real chest CT: ranked plans or a verdict, and every claim confirmed.
TEST(TrocarPlan, Lidc2PlanIsConfirmedByCheck) {
  if (!IsRegularFile(test::SharedDataPath("ct/lidc2/ct.nhdr"))) GTEST_SKIP() << "no LIDC2 data";
  const std::string out = ::testing::TempDir() + "trocar_plan_lidc2";
  std::filesystem::remove_all(out);
  const CommandRun plan = Trocar("plan --no-remedies " + test::SourcePath("patients/lidc2") + " --out " + out +
                                 " --evaluations 160 --starts 2 --polish-evaluations 10 --top 2");
  ASSERT_TRUE(plan.exit_code == 0 || plan.exit_code == 4) << plan.output;
  EXPECT_NE(plan.output.find("verdict: "), std::string::npos) << plan.output;
  const CommandRun check = Trocar("check --plan " + out + "/plan.json");
  EXPECT_EQ(check.exit_code, 0) << check.output;
  EXPECT_NE(check.output.find("all hold"), std::string::npos) << check.output;
}

// A folder that already holds a plan: planning again into it, a reader polling plan.json the
// whole time only ever sees the old plan or the new one whole (a plan written in place would be
// seen truncated); a run refused for bad input leaves both files byte for byte; no temporary
// file is left behind.
TEST(TrocarPlan, AFolderHoldingAPlanIsNeverSeenHalfOverwritten) {
  const std::string out = ::testing::TempDir() + "trocar_plan_atomic";
  std::filesystem::remove_all(out);
  const std::string base = "plan --no-remedies " + test::SourcePath("patients/phantom-default") + " --out " +
                           out + " --evaluations 60 --starts 2 --polish-evaluations 4 --top 1 " +
                           "--no-robustness --samples 2 --baseline none";
  CommandRun first = Trocar(base + " --seed 1");
  ASSERT_TRUE(first.exit_code == 0 || first.exit_code == 4) << first.output;
  const std::string old_plan = ReadTextFile(out + "/plan.json");
  const std::string old_ports = ReadTextFile(out + "/ports.mrk.json");

  CommandRun refused = Trocar(base + " --seed 2 --time-limit -1");
  EXPECT_EQ(refused.exit_code, 1) << refused.output;
  EXPECT_EQ(ReadTextFile(out + "/plan.json"), old_plan);
  EXPECT_EQ(ReadTextFile(out + "/ports.mrk.json"), old_ports);

  std::atomic<bool> done{false};
  CommandRun second;
  std::thread writer([&] {
    second = Trocar(base + " --seed 2");
    done = true;
  });
  int reads = 0, torn = 0;
  while (!done) {
    std::ifstream in(out + "/plan.json", std::ios::binary);
    const std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
    ++reads;
    const auto last = text.find_last_not_of(" \n");
    if (text != old_plan && (last == std::string::npos || text[last] != '}')) ++torn;
  }
  writer.join();
  ASSERT_TRUE(second.exit_code == 0 || second.exit_code == 4) << second.output;
  EXPECT_EQ(torn, 0) << "of " << reads << " reads";
  EXPECT_NE(ReadTextFile(out + "/plan.json"), old_plan);  // the new seed's plan is in place
  for (const auto& entry : std::filesystem::directory_iterator(out))
    EXPECT_EQ(entry.path().filename().string().find(".tmp"), std::string::npos) << entry.path();
  RecordProperty("reads_while_writing", reads);
}

// trocar verify: verified motions added to a plan, re-ranked, confirmed by check --plan (its own
// collision checker at every re-check step); a path moved into a collision is caught; a plan
// whose robot changed is refused.
TEST(TrocarVerify, AddsMotionsThatCheckConfirmsAndCatchesATamperedPath) {
  const std::string out = ::testing::TempDir() + "trocar_verify_cli";
  std::filesystem::remove_all(out);
  const CommandRun plan =
      Trocar("plan --no-remedies " + test::SourcePath("patients/phantom-default") + " --out " + out +
             " --arms psm1 --samples 3 --evaluations 120 --starts 2 --polish-evaluations 10 "
             "--top 2 --no-robustness --no-verify");
  ASSERT_TRUE(plan.exit_code == 0 || plan.exit_code == 4) << plan.output;
  EXPECT_EQ(plan.output.find("verified motions"), std::string::npos) << plan.output;
  const CommandRun verify = Trocar("verify " + out + "/plan.json --motion-threads 2");
  ASSERT_TRUE(verify.exit_code == 0 || verify.exit_code == 4) << verify.output;
  EXPECT_NE(verify.output.find("verified motions: "), std::string::npos) << verify.output;
  EXPECT_NE(verify.output.find("verified verdict: "), std::string::npos) << verify.output;
  nlohmann::json doc = nlohmann::json::parse(ReadTextFile(out + "/plan.json"));
  ASSERT_TRUE(doc["plans"][0].contains("verification")) << doc.dump().substr(0, 500);
  ASSERT_TRUE(doc["verdict"].contains("verified"));
  // Re-ranked by the verified rank score.
  for (std::size_t k = 1; k < doc["plans"].size(); ++k) {
    EXPECT_GE(doc["plans"][k - 1]["verification"]["rank_score"].get<double>(),
              doc["plans"][k]["verification"]["rank_score"].get<double>());
    EXPECT_EQ(doc["plans"][k]["rank"].get<int>(), static_cast<int>(k) + 1);
  }
  const CommandRun check = Trocar("check --plan " + out + "/plan.json");
  EXPECT_EQ(check.exit_code, 0) << check.output;
  // A solved motion whose last waypoint is pushed to the insertion limit: into the patient.
  bool tampered = false;
  for (auto& p : doc["plans"]) {
    for (auto& m : p["verification"]["motions"]) {
      if (tampered || !m["solved"].get<bool>()) continue;
      const auto& joints = m["joints"];
      for (std::size_t c = 0; c < joints.size(); ++c) {
        if (joints[c].get<std::string>().find("insertion") == std::string::npos) continue;
        m["waypoints"].back()[c] = 0.24;
        tampered = true;
      }
    }
  }
  ASSERT_TRUE(tampered) << "no solved motion to tamper with";
  WriteFileAtomically(out + "/tampered.json", doc.dump(1));
  const CommandRun bad = Trocar("check --plan " + out + "/tampered.json");
  EXPECT_EQ(bad.exit_code, 3) << bad.output;
  // The tip driven 24 cm in: in collision along the way, or (in the operation's world the heart
  // has fallen back, and the thorax has room) ending far from its target. Either fails the claim.
  EXPECT_TRUE(bad.output.find("claimed verified, but") != std::string::npos ||
              bad.output.find("ends with the tool tip") != std::string::npos)
      << bad.output;
  // A waypoint far outside its joint's range: a failed claim at once, not billions of states.
  doc = nlohmann::json::parse(ReadTextFile(out + "/tampered.json"));
  for (auto& p : doc["plans"]) {
    for (auto& m : p["verification"]["motions"]) {
      if (m["solved"].get<bool>()) m["waypoints"].back()[0] = 1e9;
    }
  }
  WriteFileAtomically(out + "/far.json", doc.dump(1));
  const CommandRun far = Trocar("check --plan " + out + "/far.json");
  EXPECT_EQ(far.exit_code, 3) << far.output;
  EXPECT_NE(far.output.find("outside"), std::string::npos) << far.output;
  // verify takes the plan as written: its nominal pose with the instrument pushed to its
  // insertion limit (into the patient) makes every motion an invalid start, named.
  doc = nlohmann::json::parse(ReadTextFile(out + "/plan.json"));
  for (auto& p : doc["plans"]) {
    for (auto& [name, value] : p["q_nominal"].items()) {
      if (name.find("insertion") != std::string::npos) value = 0.24;
    }
  }
  WriteFileAtomically(out + "/deep.json", doc.dump(1));
  const CommandRun deep = Trocar("verify " + out + "/deep.json");
  EXPECT_EQ(deep.exit_code, 4) << deep.output;
  EXPECT_NE(deep.output.find("invalid start: the start pose is not valid: collision"),
            std::string::npos)
      << deep.output;
  EXPECT_EQ(deep.output.find("verified motions: 0 of"), deep.output.find("verified motions: "))
      << deep.output;
  // A plan whose robot file changed since: refused, naming it.
  doc = nlohmann::json::parse(ReadTextFile(out + "/plan.json"));
  doc["inputs"]["robot_hash"] = "fnv1a64:0000000000000000";
  WriteFileAtomically(out + "/other.json", doc.dump(1));
  const CommandRun refused = Trocar("verify " + out + "/other.json");
  EXPECT_EQ(refused.exit_code, 1) << refused.output;
  EXPECT_NE(refused.output.find("changed since the plan was made"), std::string::npos)
      << refused.output;
  const CommandRun unknown = Trocar("verify " + out + "/plan.json --planner rrt-connect");
  EXPECT_EQ(unknown.exit_code, 1) << unknown.output;
  EXPECT_NE(unknown.output.find("rrtconnect"), std::string::npos) << unknown.output;
}

// `--ports template` plans the template's ports alone (the cart searched for them) and says so in
// the plan file; `--ports FILE` takes a surgeon's point list (here the template's own ports, in
// mm, labelled by arm) to the same spaces; a file without a point for an arm, or no such file, is
// refused naming it, and nothing is written.
TEST(TrocarPlan, GivenPortsArePlannedAsGivenAndABadPortsFileIsRefused) {
  const std::string out = ::testing::TempDir() + "trocar_plan_ports";
  std::filesystem::remove_all(out);
  const std::string base = "plan --no-remedies " + test::SourcePath("patients/phantom-default") +
                           " --polish-evaluations 10 --no-robustness --samples 2 --out ";
  const CommandRun t = Trocar(base + out + "/template --ports template");
  ASSERT_TRUE(t.exit_code == 0 || t.exit_code == 4) << t.output;
  EXPECT_NE(t.output.find("ports given: template"), std::string::npos) << t.output;
  const nlohmann::json doc = nlohmann::json::parse(ReadTextFile(out + "/template/plan.json"));
  EXPECT_NE(doc.at("ports_given").at("what").get<std::string>().find("template"), std::string::npos);
  ASSERT_EQ(doc.at("plans").size(), 1u);
  nlohmann::json points = nlohmann::json::array();
  std::map<std::string, std::string> space;
  for (const auto& port : doc.at("plans")[0].at("ports")) {
    const auto p = port.at("curve_P");
    points.push_back({{"label", port.at("arm")},
                      {"position", {p[0].get<double>() * 1e3, p[1].get<double>() * 1e3,
                                    p[2].get<double>() * 1e3}}});
    space[port.at("arm")] = port.at("candidate");
  }
  auto write = [&](const nlohmann::json& pts) {
    const nlohmann::json file = {
        {"markups",
         {{{"type", "Fiducial"}, {"name", "mine"}, {"coordinateSystem", "LPS"},
           {"coordinateUnits", "mm"}, {"controlPoints", pts}}}}};
    WriteFileAtomically(out + "/mine.mrk.json", file.dump());
    return out + "/mine.mrk.json";
  };
  const CommandRun mine = Trocar(base + out + "/mine --ports " + write(points));
  ASSERT_TRUE(mine.exit_code == 0 || mine.exit_code == 4) << mine.output;
  const nlohmann::json mine_doc = nlohmann::json::parse(ReadTextFile(out + "/mine/plan.json"));
  EXPECT_NE(mine_doc.at("ports_given").at("what").get<std::string>().find("surgeon"),
            std::string::npos);
  for (const auto& port : mine_doc.at("plans")[0].at("ports"))
    EXPECT_EQ(port.at("candidate"), space[port.at("arm")]) << port.dump();
  nlohmann::json two = points;
  const std::string dropped = two.back().at("label");
  two.erase(two.size() - 1);
  const CommandRun missing = Trocar(base + out + "/bad --ports " + write(two));
  EXPECT_EQ(missing.exit_code, 1) << missing.output;
  EXPECT_NE(missing.output.find("no point for arm " + dropped), std::string::npos) << missing.output;
  EXPECT_NE(missing.output.find("mine.mrk.json"), std::string::npos) << missing.output;
  EXPECT_FALSE(std::filesystem::exists(out + "/bad/plan.json"));
  // The same file as the baseline beside optimised plans: refused before the search.
  const CommandRun bad_baseline = Trocar(base + out + "/bad --baseline " + out + "/mine.mrk.json");
  EXPECT_EQ(bad_baseline.exit_code, 1) << bad_baseline.output;
  EXPECT_NE(bad_baseline.output.find("no point for arm " + dropped), std::string::npos)
      << bad_baseline.output;
  EXPECT_EQ(bad_baseline.output.find("plan 1:"), std::string::npos) << bad_baseline.output;
  EXPECT_FALSE(std::filesystem::exists(out + "/bad/plan.json"));
  const CommandRun none = Trocar(base + out + "/bad --ports " + out + "/none.mrk.json");
  EXPECT_EQ(none.exit_code, 1) << none.output;
  EXPECT_NE(none.output.find("--ports"), std::string::npos) << none.output;
  EXPECT_FALSE(std::filesystem::exists(out + "/bad/plan.json"));
}

TEST(TrocarPlan, BadOptionsAreRefusedNamingThem) {
  const std::string out = ::testing::TempDir() + "trocar_plan_bad";
  CommandRun r = Trocar("plan " + test::SourcePath("patients/phantom-default") + " --out " + out +
                        " --algorithm annealing");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("direct-l, crs2-lm, isres, mlsl, exhaustive"), std::string::npos)
      << r.output;
  r = Trocar("plan " + test::SourcePath("patients/phantom-default") + " --out " + out +
             " --time-limit 0");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("--time-limit: 0 s"), std::string::npos) << r.output;
  // The library's field names are the CLI's flags here, also where they are spelt otherwise
  // (top_k is --top; the motions' time_limit is --motion-time, not the search's --time-limit).
  r = Trocar("plan " + test::SourcePath("patients/phantom-default") + " --out " + out + " --top 0");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("--top: 0"), std::string::npos) << r.output;
  EXPECT_EQ(r.output.find("top_k"), std::string::npos) << r.output;
  r = Trocar("plan " + test::SourcePath("patients/phantom-default") + " --out " + out +
             " --motion-time 0");
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("--motion-time: 0 s"), std::string::npos) << r.output;
  r = Trocar("plan " + test::SourcePath("patients/phantom-default") + " --out " + out +
             " --robot " + test::SourcePath("robots/pa10/pa10.yaml"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("no RCM frame"), std::string::npos) << r.output;
  for (const char* heights : {"1.2,0.9", "0.2,1.0", "high", "0.9"}) {
    r = Trocar("plan " + test::SourcePath("patients/phantom-default") + " --out " + out +
               " --table-height " + heights);
    EXPECT_EQ(r.exit_code, 1) << heights << ": " << r.output;
    EXPECT_NE(r.output.find("--table-height: '" + std::string(heights) + "'"), std::string::npos)
        << r.output;
  }
  r = Trocar("plan /nonexistent/case --out " + out);
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_FALSE(std::filesystem::exists(out + "/plan.json"));
  r = Trocar("check --plan " + test::SourcePath("README.md"));
  EXPECT_EQ(r.exit_code, 1) << r.output;
  EXPECT_NE(r.output.find("not a plan"), std::string::npos) << r.output;
}

}  // namespace
}  // namespace trocar

namespace trocar {
namespace {

using test::FreePort;

double RmsPositionError(const std::string& output) {
  const auto at = output.find("position error:    RMS ");
  if (at == std::string::npos) return NAN;
  return std::stod(output.substr(at + 23));
}

// Issue #16: the PSM tip driven around a circle by a device over OpenIGTLink on localhost tracks
// as the same circle does headless (both in real time): no more than 10 % worse, and not less than
// half (a circle the network shrank or lost would track differently). Better is no failure of the
// network: the headless run shares two cores with the server and the device, and a CI run
// measured it 14-19 % worse than the network's in all three tries (stop 59).
TEST(TrocarTeleopNetwork, ACircleThroughTheNetworkTracksAsTheSameCircleHeadless) {
  const std::string psm = test::SourcePath("robots/davinci-classic/psm.yaml");
  // Both runs are real time, on a machine other tests load too: they run at the same time, so
  // that both meet the same load (the property compared is the network's, not the machine's), and
  // up to three tries are taken; one within the bounds with nothing dropped passes (each try's
  // figures are printed on failure).
  std::string tries;
  bool matched = false;
  std::string address;
  for (int attempt = 0; attempt < 3 && !matched; ++attempt) {
    address = "127.0.0.1:" + std::to_string(FreePort());
    CommandRun listening{-1, ""};
    CommandRun headless{-1, ""};
    std::thread server([&] {
      listening = Trocar("teleop --robot " + psm + " --listen " + address + " --duration 3 --wait 20");
    });
    std::thread alone_run([&] { headless = Trocar("teleop --robot " + psm + " --input circle --duration 3 --realtime"); });
    const CommandRun device = Trocar("device --connect " + address + " --input circle --duration 3.5 --name hand");
    server.join();
    alone_run.join();
    ASSERT_EQ(listening.exit_code, 0) << listening.output << device.output;
    EXPECT_NE(listening.output.find("device 'hand': "), std::string::npos) << listening.output;
    EXPECT_NE(listening.output.find("latency, arrival to command"), std::string::npos) << listening.output;
    // Nothing dropped is part of a try's result, not a failure of its own: a try on a loaded
    // machine may drop a late message, and another try is taken.
    const bool none_dropped = listening.output.find(" 0 dropped") != std::string::npos;
    ASSERT_EQ(headless.exit_code, 0) << headless.output;
    const double network = RmsPositionError(listening.output), alone = RmsPositionError(headless.output);
    ASSERT_TRUE(std::isfinite(network) && std::isfinite(alone)) << listening.output << headless.output;
    tries += "network " + std::to_string(network) + " mm, headless " + std::to_string(alone) +
             " mm" + (none_dropped ? "" : ", messages dropped") + "; ";
    matched = none_dropped && network <= 1.10 * alone && network >= 0.5 * alone;
  }
  EXPECT_TRUE(matched) << tries;
  // The device is told when the trocar goes, and a port in use is a clear error.
  CommandRun second{-1, ""};
  std::thread holder([&] { second = Trocar("teleop --robot " + psm + " --listen " + address + " --duration 1 --wait 3"); });
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  const CommandRun busy = Trocar("teleop --robot " + psm + " --listen " + address + " --duration 1 --wait 1");
  holder.join();
  EXPECT_EQ(busy.exit_code, 1) << busy.output;
  EXPECT_NE(busy.output.find("already in use"), std::string::npos) << busy.output;
  EXPECT_EQ(second.exit_code, 1) << second.output;  // nobody came
  EXPECT_NE(second.output.find("no device sent a pose"), std::string::npos) << second.output;
}

// Issue #16: two devices drive the cart's two PSMs at once through a device file, a third is a
// teaching pointer; each device gets force messages back and every connection the arms' poses.
TEST(TrocarTeleopNetwork, TwoDevicesDriveTwoArmsAndAPointerFromADeviceFile) {
  const std::string cart = test::SourcePath("robots/davinci-classic/cart.yaml");
  const auto dir = std::filesystem::temp_directory_path() / ("trocar_devices_cli_" + std::to_string(::getpid()));
  std::filesystem::create_directories(dir);
  const std::string devices = (dir / "devices.yaml").string();
  std::ofstream(devices) << "devices:\n"
                            "  - {name: left, arm: psm1_tool, units: mm}\n"
                            "  - {name: right, arm: psm2_tool, units: m, scale: 2}\n"
                            "  - {name: senior, pointer: true}\n";
  const std::string address = "127.0.0.1:" + std::to_string(FreePort());
  CommandRun listening{-1, ""};
  std::thread server([&] {
    listening = Trocar("teleop --robot " + cart + " --listen " + address + " --devices " + devices +
                       " --duration 3 --wait 20");
  });
  CommandRun right{-1, ""}, senior{-1, ""};
  std::thread second([&] {
    right = Trocar("device --connect " + address + " --name right --units 1 --input sinusoid --amplitude 0.02 "
                   "--duration 3.5");
  });
  std::thread third([&] {
    senior = Trocar("device --connect " + address + " --name senior --input circle --rate 200 --duration 3.5");
  });
  const CommandRun left = Trocar("device --connect " + address + " --name left --input circle --duration 3.5 "
                                 "--clutch 1.5:2");
  server.join();
  second.join();
  third.join();
  std::filesystem::remove_all(dir);
  ASSERT_EQ(listening.exit_code, 0) << listening.output << left.output << right.output;
  const std::string& out = listening.output;
  // Both arms tracked their own device; the pointer followed its own.
  const double rms1 = RmsPositionError(out);
  ASSERT_TRUE(std::isfinite(rms1)) << out;
  EXPECT_LT(rms1, 1.0) << out;
  const auto arm2 = out.find("  arm psm2_tool: position error RMS ");
  ASSERT_NE(arm2, std::string::npos) << out;
  EXPECT_LT(std::stod(out.substr(arm2 + 36)), 1.0) << out;
  EXPECT_NE(out.find("pointer 'senior'"), std::string::npos) << out;
  // Headless: a status line a second with each device's rate, drops and latency.
  EXPECT_NE(out.find("status: left: "), std::string::npos) << out;
  EXPECT_NE(out.find("; right: "), std::string::npos) << out;
  for (const char* d : {"device 'left': ", "device 'right': ", "device 'senior': "})
    EXPECT_NE(out.find(d), std::string::npos) << d << "\n" << out;
  // The clutch window held psm1 about half a second (at 1 kHz), and nothing was dropped.
  const auto samples = out.find("  samples: ");
  ASSERT_NE(samples, std::string::npos) << out;
  const auto held = out.find(" held)", samples);
  const long held_steps = std::stol(out.substr(out.rfind(", ", held) + 2));
  EXPECT_NEAR(held_steps, 500, 60) << out;
  EXPECT_EQ(out.find("dropped (crc 1"), std::string::npos) << out;
  // Each device heard force messages and the arms' poses.
  for (const CommandRun* d : {&left, static_cast<const CommandRun*>(&right)}) {
    ASSERT_EQ(d->exit_code, 0) << d->output;
    EXPECT_NE(d->output.find(" SENSOR"), std::string::npos) << d->output;
    EXPECT_NE(d->output.find(" TRANSFORM"), std::string::npos) << d->output;
    EXPECT_EQ(d->output.find(" bad ("), std::string::npos) << d->output;
  }
  EXPECT_NE(out.find("poses streamed (world frame, mm"), std::string::npos) << out;
}

}  // namespace
}  // namespace trocar
