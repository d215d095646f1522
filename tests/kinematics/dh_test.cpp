#include <random>

#include <gtest/gtest.h>

#include "common/geometry.hpp"
#include "kinematics/dh_extraction.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "robot/dh_table.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using kinematics::ForwardKinematics;
using kinematics::ToolPoseInBase;
using robot::DhConvention;
using robot::DhTable;
using robot::RobotModel;
using robot::RobotState;
using test::CompareMatrices;

constexpr double kTol = 1e-12;

// The tree built from a DH table and the table's own product formula agree.
void ExpectTreeMatchesTable(const RobotModel& model, const DhTable& table, unsigned seed) {
  RobotState state(model);
  std::mt19937 rng(seed);
  for (int trial = 0; trial < 1000; ++trial) {
    const Eigen::VectorXd q = test::RandomConfiguration(model, &rng);
    ASSERT_TRUE(ForwardKinematics(model, q, &state).ok());
    ASSERT_TRUE(CompareMatrices(ToolPoseInBase(model, state).matrix(),
                                robot::DhToolPose(table, q).matrix(), kTol))
        << "q = " << q.transpose();
  }
}

DhTable Puma560Standard() {
  // PUMA 560 in the standard (distal) convention (Corke's mdl_puma560 values).
  DhTable t;
  t.convention = DhConvention::kStandard;
  const double rows[6][3] = {  // a, alpha, d
      {0, M_PI / 2, 0}, {0.4318, 0, 0}, {0.0203, -M_PI / 2, 0.15005},
      {0, M_PI / 2, 0.4318}, {0, -M_PI / 2, 0}, {0, 0, 0}};
  for (int i = 0; i < 6; ++i) {
    robot::DhRow row;
    row.joint = "j" + std::to_string(i + 1);
    row.link = "l" + std::to_string(i + 1);
    row.a = rows[i][0];
    row.alpha = rows[i][1];
    row.d = rows[i][2];
    row.offset = 0.1 * i;
    row.limits.lower = -2.5;
    row.limits.upper = 2.5;
    t.rows.push_back(row);
  }
  t.X_B0 = MakeTransform({0.1, 0.2, 0.6}, {0.1, -0.2, 0.3});
  t.X_NT = MakeTransform({0, 0, 0.05}, {0, 0, 0.5});
  return t;
}

RobotModel BuildFromTable(const DhTable& table) {
  robot::RobotModelBuilder builder("from_table", "test");
  robot::AddDhChain(table, &builder);
  return builder.Build();
}

TEST(DhTable, StandardConventionTreeMatchesTheTable) {
  const DhTable table = Puma560Standard();
  ExpectTreeMatchesTable(BuildFromTable(table), table, 1);
}

TEST(DhTable, StandardConventionWithPrismaticJointsMatchesTheTable) {
  DhTable table = Puma560Standard();
  table.rows[2].type = robot::JointType::kPrismatic;
  table.rows[2].theta = 0.3;
  table.rows[2].limits.lower = -0.2;
  table.rows[2].limits.upper = 0.2;
  ExpectTreeMatchesTable(BuildFromTable(table), table, 2);
}

TEST(DhTable, ModifiedConventionFilesMatchTheirTables) {
  for (const char* file : {"robots/pa10/pa10.yaml", "robots/pa10/pa10_instrument.yaml",
                           "robots/prismatic-test/prismatic10.yaml"}) {
    SCOPED_TRACE(file);
    const std::string path = test::SourcePath(file);
    ExpectTreeMatchesTable(robot::LoadRobot(path), robot::LoadDhTable(path), 3);
  }
}

// Extraction: the equivalent table reproduces the model's tool pose everywhere.
void ExpectExtractionRoundTrips(const RobotModel& model, unsigned seed) {
  std::string why;
  const auto table = kinematics::ExtractModifiedDh(model, &why);
  ASSERT_TRUE(table.has_value()) << why;
  ExpectTreeMatchesTable(model, *table, seed);
}

TEST(DhExtraction, BundledSerialRobotsRoundTrip) {
  for (const char* file : {"robots/pa10/pa10.urdf", "robots/pa10/pa10_instrument.yaml",
                           "robots/prismatic-test/prismatic10.yaml"}) {
    SCOPED_TRACE(file);
    ExpectExtractionRoundTrips(robot::LoadRobot(test::SourcePath(file)), 4);
  }
  ExpectExtractionRoundTrips(BuildFromTable(Puma560Standard()), 5);
}

TEST(DhExtraction, Pa10UrdfGivesThePublishedTable) {
  const RobotModel model = robot::LoadRobot(test::SourcePath("robots/pa10/pa10.urdf"));
  std::string why;
  const auto table = kinematics::ExtractModifiedDh(model, &why);
  ASSERT_TRUE(table.has_value()) << why;
  const double alpha[7] = {0, -M_PI / 2, M_PI / 2, -M_PI / 2, M_PI / 2, -M_PI / 2, M_PI / 2};
  const double d[7] = {0, 0, 0.45, 0, 0.48, 0, 0};
  for (int i = 0; i < 7; ++i) {
    EXPECT_NEAR(table->rows[i].alpha, alpha[i], 1e-12) << i;
    EXPECT_NEAR(table->rows[i].a, 0.0, 1e-12) << i;
    EXPECT_NEAR(table->rows[i].d, d[i], 1e-12) << i;
    EXPECT_NEAR(table->rows[i].offset, 0.0, 1e-12) << i;
  }
  EXPECT_TRUE(CompareMatrices(table->X_B0.matrix(),
                              MakeTransform({0, 0, 0.317}, {0, 0, 0}).matrix(), 1e-12));
  EXPECT_TRUE(CompareMatrices(table->X_NT.matrix(),
                              MakeTransform({0, 0, 0.07}, {0, 0, 0}).matrix(), 1e-12));
}

TEST(DhExtraction, RandomSerialChainsRoundTrip) {
  // Random chains with random joint frames; a third of the axes are made parallel to, and a
  // third intersecting, the previous one, the special cases of the common-normal construction.
  std::mt19937 rng(77);
  std::uniform_real_distribution<double> u(-1, 1);
  std::uniform_int_distribution<int> kind(0, 2), joints(1, 8);
  for (int trial = 0; trial < 200; ++trial) {
    robot::RobotModelBuilder b("chain", "test");
    b.AddLink("l0");
    const int n = joints(rng);
    Eigen::Isometry3d X_BP = Eigen::Isometry3d::Identity();
    Eigen::Vector3d previous_axis_B = Eigen::Vector3d::UnitZ(), previous_origin_B = Eigen::Vector3d::Zero();
    for (int i = 0; i < n; ++i) {
      const std::string child = "l" + std::to_string(i + 1);
      b.AddLink(child);
      auto& j = b.AddJoint("j" + std::to_string(i + 1));
      j.type = u(rng) > -0.6 ? robot::JointType::kRevolute : robot::JointType::kPrismatic;
      j.parent = "l" + std::to_string(i);
      j.child = child;
      j.limits.lower = -1.5;
      j.limits.upper = 1.5;
      j.X_PJ = MakeTransform({0.3 * u(rng), 0.3 * u(rng), 0.3 * u(rng)},
                             {M_PI * u(rng), M_PI * u(rng), M_PI * u(rng)});
      Eigen::Vector3d axis_B(u(rng), u(rng), u(rng));
      const int k = kind(rng);
      const Eigen::Isometry3d X_BJ = X_BP * j.X_PJ;
      if (i > 0 && k == 0) axis_B = previous_axis_B;                           // parallel
      if (i > 0 && k == 1) axis_B = previous_origin_B - X_BJ.translation();  // intersecting
      if (axis_B.norm() < 1e-3) axis_B = Eigen::Vector3d::UnitX();
      axis_B.normalize();
      j.axis = X_BJ.linear().transpose() * axis_B;
      previous_axis_B = axis_B;
      previous_origin_B = X_BJ.translation();
      X_BP = X_BJ;
    }
    b.SetTool({"tool", "l" + std::to_string(n), MakeTransform({0.1, 0, 0.2}, {0.3, 0.2, 0.1})});
    ExpectExtractionRoundTrips(b.Build(), 100 + trial);
    if (::testing::Test::HasFailure()) break;
  }
}

TEST(DhExtraction, ClosedChainsHaveNoTable) {
  const RobotModel model =
      robot::LoadRobot(test::SourcePath("robots/parallelogram/parallelogram.urdf"));
  std::string why;
  EXPECT_FALSE(kinematics::ExtractModifiedDh(model, &why).has_value());
  EXPECT_NE(why.find("serial chain"), std::string::npos) << why;
}

}  // namespace
}  // namespace trocar
