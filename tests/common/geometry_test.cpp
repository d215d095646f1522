#include "common/geometry.hpp"

#include <filesystem>
#include <fstream>
#include <random>

#include <sys/wait.h>
#include <unistd.h>
#include <gtest/gtest.h>
#include <sys/resource.h>

#include <csignal>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

TEST(ParseScalarExpression, AcceptsNumbersPiAndDegrees) {
  double v = 0.0;
  ASSERT_TRUE(ParseScalarExpression("1.25", &v));
  EXPECT_EQ(v, 1.25);
  ASSERT_TRUE(ParseScalarExpression("-pi/2", &v));
  EXPECT_EQ(v, -M_PI / 2);
  ASSERT_TRUE(ParseScalarExpression("3*pi/4", &v));
  EXPECT_DOUBLE_EQ(v, 3 * M_PI / 4);
  ASSERT_TRUE(ParseScalarExpression("2*pi", &v));
  EXPECT_DOUBLE_EQ(v, 2 * M_PI);
  ASSERT_TRUE(ParseScalarExpression("90 deg", &v));
  EXPECT_DOUBLE_EQ(v, M_PI / 2);
  ASSERT_TRUE(ParseScalarExpression("-30deg", &v));
  EXPECT_DOUBLE_EQ(v, -M_PI / 6);
}

TEST(ParseScalarExpression, RejectsOtherText) {
  double v = 7.0;
  for (const char* text : {"", "abc", "pi/0", "1.5x", "pi*2", "deg", "2 pi"}) {
    EXPECT_FALSE(ParseScalarExpression(text, &v)) << text;
  }
  EXPECT_EQ(v, 7.0);  // untouched
}

// Issue #43: "placed within 1.69614e-05 mm" is noise to a reader. An error under the resolution
// says so; a larger one is given to the resolution's decimals, rounded, not cut.
TEST(FormatError, SaysUnderTheResolutionOrTheValueToItsDecimals) {
  EXPECT_EQ(FormatError(1.69614e-05, "mm"), "under 0.01 mm");
  EXPECT_EQ(FormatError(0.0, "deg"), "under 0.01 deg");
  EXPECT_EQ(FormatError(0.379999, "mm"), "0.38 mm");
  EXPECT_EQ(FormatError(12.345, "deg", 0.1), "12.3 deg");
  EXPECT_EQ(FormatError(0.04, "deg", 0.1), "under 0.1 deg");
  EXPECT_EQ(FormatError(7.0, "mm", 1.0), "7 mm");
}

TEST(RotationFromRpy, RoundTripsOverRandomAngles) {
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> angle(-M_PI, M_PI), pitch(-1.5, 1.5);
  for (int i = 0; i < 1000; ++i) {
    const Eigen::Vector3d rpy(angle(rng), pitch(rng), angle(rng));
    const Eigen::Matrix3d R = RotationFromRpy(rpy);
    EXPECT_TRUE(test::CompareMatrices(RotationFromRpy(RpyFromRotation(R)), R, 1e-12));
    // URDF convention: fixed-axis X, Y, Z.
    const Eigen::Matrix3d expected = RotZ(rpy.z()).linear() *
                                     Eigen::AngleAxisd(rpy.y(), Eigen::Vector3d::UnitY()).toRotationMatrix() *
                                     RotX(rpy.x()).linear();
    EXPECT_TRUE(test::CompareMatrices(R, expected, 1e-14));
  }
}

TEST(WrapAngle, StaysInHalfOpenInterval) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> angle(-50, 50);
  for (int i = 0; i < 1000; ++i) {
    const double a = angle(rng);
    const double w = WrapAngle(a);
    EXPECT_GT(w, -M_PI);
    EXPECT_LE(w, M_PI);
    EXPECT_NEAR(std::remainder(a - w, 2 * M_PI), 0.0, 1e-12);
  }
}

TEST(WriteFileAtomically, WritesWholeFileAndLeavesNoTemporary) {
  const auto dir = std::filesystem::temp_directory_path() / "trocar_atomic_test";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "out.txt").string();
  WriteFileAtomically(path, "first");
  WriteFileAtomically(path, "second version");
  EXPECT_EQ(ReadTextFile(path), "second version");
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    (void)entry;
    ++files;
  }
  EXPECT_EQ(files, 1);
  std::filesystem::remove_all(dir);
}

// A write that fails half-way (the file-size limit of the process stops it after 4 KiB of 1 MiB)
// leaves the target exactly as it was and no temporary beside it: a writer that wrote the target
// in place would leave 4 KiB of the new content.
TEST(WriteFileAtomically, AWriteFailingHalfWayLeavesTheOldContent) {
  const auto dir = std::filesystem::temp_directory_path() / "trocar_atomic_failure";
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const std::string path = (dir / "plan.json").string();
  WriteFileAtomically(path, "old content");
  rlimit saved{};
  ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &saved), 0);
  const auto previous = std::signal(SIGXFSZ, SIG_IGN);  // EFBIG instead of a signal
  rlimit small = saved;
  small.rlim_cur = 4096;
  ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);
  bool threw = false;
  try {
    WriteFileAtomically(path, std::string(1 << 20, 'x'));
  } catch (const Error& e) {
    threw = true;
    EXPECT_NE(std::string(e.what()).find("plan.json"), std::string::npos) << e.what();
  }
  setrlimit(RLIMIT_FSIZE, &saved);
  std::signal(SIGXFSZ, previous);
  EXPECT_TRUE(threw);
  EXPECT_EQ(ReadTextFile(path), "old content");
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) {
    EXPECT_EQ(entry.path().filename(), "plan.json") << "left behind: " << entry.path();
    ++files;
  }
  EXPECT_EQ(files, 1);
  std::filesystem::remove_all(dir);
}

// A writer killed half-way leaves its temporary; the next write of the same target removes it,
// and only it: not a live writer's temporary, not another target's, not a file merely named alike.
TEST(WriteFileAtomically, AKilledWritersTemporaryIsRemovedByTheNextWriteOfItsTargetOnly) {
  const auto dir = std::filesystem::temp_directory_path() /
                   ("trocar_atomic_stale_" + std::to_string(::getpid()));
  std::filesystem::remove_all(dir);
  std::filesystem::create_directories(dir);
  const pid_t gone = ::fork();  // a process that has ended: its pid names a dead writer
  if (gone == 0) ::_exit(0);
  ASSERT_GT(gone, 0);
  ASSERT_EQ(::waitpid(gone, nullptr, 0), gone);
  const std::string dead = std::to_string(gone), live = std::to_string(::getppid());
  const std::vector<std::string> stale = {"plan.json.tmp." + dead + ".0-123"};
  const std::vector<std::string> kept = {"plan.json.tmp." + live + ".0-5",   // a live writer's
                                         "other.json.tmp." + dead + ".0-7",  // another target's
                                         "plan.json.tmp123456",              // not this scheme
                                         "plan.json.tmp.x.0", "plan.json.tmp.." + dead};
  for (const auto& name : stale) WriteFileAtomically((dir / name).string(), std::string(1000, 's'));
  for (const auto& name : kept) WriteFileAtomically((dir / name).string(), "k");
  WriteFileAtomically((dir / "plan.json").string(), "new");
  EXPECT_EQ(ReadTextFile((dir / "plan.json").string()), "new");
  for (const auto& name : stale) EXPECT_FALSE(std::filesystem::exists(dir / name)) << name;
  for (const auto& name : kept) EXPECT_TRUE(std::filesystem::exists(dir / name)) << name;
  std::filesystem::remove_all(dir);
}

TEST(WriteFileAtomically, FailureNamesThePathAndKeepsNothing) {
  try {
    WriteFileAtomically("/nonexistent-folder/x/out.txt", "data");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("/nonexistent-folder/x/out.txt"), std::string::npos)
        << e.what();
  }
}

TEST(ReadTextFile, MissingFileNamesIt) {
  try {
    ReadTextFile("/no/such/file.yaml");
    FAIL() << "expected an error";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()), "/no/such/file.yaml: file not found");
  }
}

}  // namespace
}  // namespace trocar
