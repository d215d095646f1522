#include <filesystem>
#include <fstream>
#include <random>
#include <cstdlib>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using kinematics::ForwardKinematics;
using kinematics::ToolPoseInBase;
using robot::JointDrive;
using robot::LoadRobot;
using robot::RobotModel;
using robot::RobotState;
using test::CompareMatrices;
using test::SourcePath;

constexpr double kPoseTolerance = 1e-12;  // metres, and rotation-matrix entries

struct BundledRobot {
  const char* file;
  int num_positions;
};

const BundledRobot kBundledRobots[] = {
    {"robots/pa10/pa10.yaml", 7},
    {"robots/pa10/pa10.urdf", 7},
    {"robots/pa10/pa10_instrument.yaml", 9},
    {"robots/prismatic-test/prismatic10.yaml", 13},
    {"robots/parallelogram/parallelogram.urdf", 3},
    {"robots/davinci-classic/psm.yaml", 7},
    {"robots/davinci-classic/psm_si.yaml", 7},
    {"robots/davinci-classic/ecm.yaml", 4},
    {"robots/davinci-classic/ecm_30.yaml", 4},
    {"robots/davinci-classic/suj_psm.yaml", 0},
    {"robots/davinci-classic/suj_ecm.yaml", 0},
    {"robots/davinci-classic/cart.yaml", 18},
};

TEST(LoadRobot, EveryBundledRobotLoads) {
  for (const auto& bundled : kBundledRobots) {
    const RobotModel model = LoadRobot(SourcePath(bundled.file));
    EXPECT_EQ(model.num_positions(), bundled.num_positions) << bundled.file;
    RobotState state(model);
    EXPECT_TRUE(ForwardKinematics(model, model.neutral_configuration(), &state).ok());
  }
}

TEST(LoadRobot, Pa10UrdfAndDhGiveTheSameToolPoses) {
  const RobotModel dh = LoadRobot(SourcePath("robots/pa10/pa10.yaml"));
  const RobotModel urdf = LoadRobot(SourcePath("robots/pa10/pa10.urdf"));
  ASSERT_EQ(dh.num_positions(), urdf.num_positions());
  for (int i = 0; i < dh.num_positions(); ++i) {
    const auto& a = dh.joint(dh.active_joints()[i]).limits;
    const auto& b = urdf.joint(urdf.active_joints()[i]).limits;
    EXPECT_NEAR(a.lower, b.lower, 1e-12);
    EXPECT_NEAR(a.upper, b.upper, 1e-12);
    EXPECT_NEAR(a.velocity, b.velocity, 1e-12);
  }
  RobotState s_dh(dh), s_urdf(urdf);
  std::mt19937 rng(2);
  for (int trial = 0; trial < 1000; ++trial) {
    const Eigen::VectorXd q = test::RandomConfiguration(dh, &rng);
    ASSERT_TRUE(ForwardKinematics(dh, q, &s_dh).ok());
    ASSERT_TRUE(ForwardKinematics(urdf, q, &s_urdf).ok());
    ASSERT_TRUE(CompareMatrices(ToolPoseInBase(dh, s_dh).matrix(),
                                ToolPoseInBase(urdf, s_urdf).matrix(), kPoseTolerance))
        << "q = " << q.transpose();
  }
}

TEST(LoadRobot, BasePoseMovesEveryLinkRigidly) {
  const RobotModel model = LoadRobot(SourcePath("robots/pa10/pa10.yaml"));
  RobotState at_origin(model), moved(model);
  moved.X_WB = Eigen::Translation3d(1.0, -2.0, 0.5) *
               Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized());
  std::mt19937 rng(5);
  for (int trial = 0; trial < 100; ++trial) {
    const Eigen::VectorXd q = test::RandomConfiguration(model, &rng);
    ForwardKinematics(model, q, &at_origin);
    ForwardKinematics(model, q, &moved);
    for (int l = 0; l < model.num_links(); ++l) {
      ASSERT_TRUE(CompareMatrices((moved.X_WB * at_origin.X_WL[l]).matrix(),
                                  moved.X_WL[l].matrix(), 1e-12));
    }
  }
}

TEST(LoadRobot, DefaultToolFollowsFixedJointsFromTheLastActiveJoint) {
  const RobotModel model = LoadRobot(SourcePath("robots/pa10/pa10.urdf"));
  EXPECT_EQ(model.link(model.tool_frame().link).name, "flange");
}

TEST(KinematicFrames, ActiveJointFrameHasZAlongTheAxisAtTheJoint) {
  const RobotModel model = LoadRobot(SourcePath("robots/pa10/pa10.urdf"));
  RobotState state(model);
  std::mt19937 rng(9);
  for (int trial = 0; trial < 100; ++trial) {
    ForwardKinematics(model, test::RandomConfiguration(model, &rng), &state);
    for (int j : model.active_joints()) {
      const robot::Joint& joint = model.joint(j);
      const Eigen::Isometry3d X_WK = kinematics::KinematicFramePose(model, state, joint.child_link);
      const Eigen::Vector3d axis_W = state.X_WL[joint.child_link].linear() * joint.axis_J;
      EXPECT_TRUE(CompareMatrices(X_WK.linear().col(2), axis_W, 1e-12));
      EXPECT_TRUE(CompareMatrices(X_WK.translation(),
                                  state.X_WL[joint.child_link].translation(), 1e-12));
      EXPECT_NEAR(X_WK.linear().determinant(), 1.0, 1e-12);
    }
  }
}

TEST(KinematicFrames, TwoPassiveJointsGiveTheMidpointFrame) {
  // The parallelogram's coupler carries two passive joints: its own (closure-driven) joint at its
  // origin and the loop's cut joint at (0.1, 0, 0); its frame sits between them, z along the cut
  // joint's axis, x from the first joint toward the second.
  const RobotModel model = LoadRobot(SourcePath("robots/parallelogram/parallelogram.urdf"));
  const robot::Link& coupler = model.link(model.GetLink("coupler"));
  EXPECT_TRUE(CompareMatrices(coupler.X_LK.translation(), Eigen::Vector3d(0.05, 0, 0), 1e-12));
  EXPECT_TRUE(CompareMatrices(coupler.X_LK.linear().col(0), Eigen::Vector3d::UnitX(), 1e-12));
  EXPECT_NEAR(std::abs(coupler.X_LK.linear().col(2).dot(Eigen::Vector3d::UnitY())), 1.0, 1e-12);
  // The turret has an active parent joint: its frame is on that joint's axis.
  const robot::Link& turret = model.link(model.GetLink("turret"));
  EXPECT_TRUE(CompareMatrices(turret.X_LK.linear().col(2), Eigen::Vector3d::UnitZ(), 1e-12));
}

TEST(LoadRobot, SurrolPsmLoadsWithMeshesAndMimicJoints) {
  const std::string path = test::SharedDataPath("robots/surrol-psm/psm.urdf");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const RobotModel model = LoadRobot(path);
  int mimic = 0;
  for (int j : model.dof_joints()) mimic += model.joint(j).drive == JointDrive::kMimic;
  EXPECT_EQ(mimic, 5);  // pitch end, bottom, top, front, and one gripper jaw
  EXPECT_EQ(model.num_positions(), 7);
  int meshes = 0;
  for (const auto& link : model.links()) {
    for (const auto& g : link.visuals) {
      if (g.shape == robot::Geometry::Shape::kMesh) {
        ASSERT_NE(g.mesh, nullptr) << link.name;
        EXPECT_GT(g.mesh->triangles.size(), 10u) << link.name;
        ++meshes;
      }
    }
  }
  EXPECT_GE(meshes, 10);
  // Mimic joints follow their masters through the whole tree.
  RobotState state(model);
  std::mt19937 rng(4);
  for (int trial = 0; trial < 200; ++trial) {
    ASSERT_TRUE(ForwardKinematics(model, test::RandomConfiguration(model, &rng), &state).ok());
    for (int j : model.dof_joints()) {
      const robot::Joint& joint = model.joint(j);
      if (joint.drive != JointDrive::kMimic) continue;
      const double master = state.joint_values[model.joint(joint.mimic.master).dof_index];
      EXPECT_NEAR(state.joint_values[joint.dof_index],
                  joint.mimic.multiplier * master + joint.mimic.offset, 1e-15);
    }
  }
}

TEST(LoadRobot, SurrolPsmShaftPassesThroughTheRemoteCentre) {
  // The mimic joints make the SurRoL PSM's pitch a parallelogram: whatever yaw and pitch, the
  // instrument shaft's axis passes through the fixed remote-centre link.
  const std::string path = test::SharedDataPath("robots/surrol-psm/psm.urdf");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const RobotModel model = LoadRobot(path, {false, {}});
  const int rcm = model.GetLink("psm_remote_center_link");
  const int insertion_joint = model.GetJoint("psm_main_insertion_joint");
  RobotState state(model);
  std::mt19937 rng(8);
  for (int trial = 0; trial < 200; ++trial) {
    ASSERT_TRUE(ForwardKinematics(model, test::RandomConfiguration(model, &rng), &state).ok());
    const robot::Joint& joint = model.joint(insertion_joint);
    const Eigen::Isometry3d& X_WI = state.X_WL[joint.child_link];
    const Eigen::Vector3d axis = X_WI.linear() * joint.axis_J;
    const Eigen::Vector3d to_rcm = state.X_WL[rcm].translation() - X_WI.translation();
    EXPECT_LT((to_rcm - to_rcm.dot(axis) * axis).norm(), 1e-4);
  }
}

// A unit cube as OBJ and as ASCII PLY, to check the mesh formats besides STL.
void WriteCubeMeshes(const std::string& dir) {
  const char* vertices[8] = {"0 0 0", "1 0 0", "1 1 0", "0 1 0", "0 0 1", "1 0 1", "1 1 1", "0 1 1"};
  const int faces[12][3] = {{0, 2, 1}, {0, 3, 2}, {4, 5, 6}, {4, 6, 7}, {0, 1, 5}, {0, 5, 4},
                            {1, 2, 6}, {1, 6, 5}, {2, 3, 7}, {2, 7, 6}, {3, 0, 4}, {3, 4, 7}};
  std::ofstream obj(dir + "/cube.obj");
  for (const char* v : vertices) obj << "v " << v << "\n";
  for (const auto& f : faces) obj << "f " << f[0] + 1 << " " << f[1] + 1 << " " << f[2] + 1 << "\n";
  std::ofstream ply(dir + "/cube.ply");
  ply << "ply\nformat ascii 1.0\nelement vertex 8\nproperty float x\nproperty float y\n"
         "property float z\nelement face 12\nproperty list uchar int vertex_indices\n"
         "end_header\n";
  for (const char* v : vertices) ply << v << "\n";
  for (const auto& f : faces) ply << "3 " << f[0] << " " << f[1] << " " << f[2] << "\n";
}

TEST(LoadRobot, ResolvesPackagePathsAndReadsObjAndPlyMeshes) {
  const std::string root = ::testing::TempDir() + "/trocar_pkg_test";
  std::filesystem::remove_all(root);
  std::filesystem::create_directories(root + "/my_arm/meshes");
  std::filesystem::create_directories(root + "/my_arm/urdf");
  WriteCubeMeshes(root + "/my_arm/meshes");
  const std::string urdf = root + "/my_arm/urdf/arm.urdf";
  std::ofstream(urdf) << R"(<robot name="arm"><link name="a">
      <visual><geometry><mesh filename="package://my_arm/meshes/cube.obj" scale="0.1 0.2 0.3"/>
      </geometry></visual>
      <collision><geometry><mesh filename="../meshes/cube.ply"/></geometry></collision>
      </link></robot>)";
  const RobotModel model = LoadRobot(urdf);
  const auto& visual = model.link(0).visuals.at(0);
  const auto& collision = model.link(0).collisions.at(0);
  ASSERT_NE(visual.mesh, nullptr);
  ASSERT_NE(collision.mesh, nullptr);
  EXPECT_EQ(visual.mesh->triangles.size(), 12u);
  EXPECT_EQ(collision.mesh->triangles.size(), 12u);
  Eigen::Vector3d max_corner = Eigen::Vector3d::Zero();
  for (const auto& v : visual.mesh->vertices) max_corner = max_corner.cwiseMax(v);
  EXPECT_TRUE(CompareMatrices(max_corner, Eigen::Vector3d(0.1, 0.2, 0.3), 1e-7));
  EXPECT_EQ(std::filesystem::path(visual.mesh_file),
            std::filesystem::path(root + "/my_arm/meshes/cube.obj").lexically_normal());
  // The same package found through TROCAR_PACKAGE_PATH from a URDF in an unrelated tree.
  const std::string other = ::testing::TempDir() + "/trocar_pkg_other/urdf";
  std::filesystem::create_directories(other);
  const std::string elsewhere = other + "/elsewhere.urdf";
  std::ofstream(elsewhere) << R"(<robot name="arm2"><link name="a"><visual><geometry>
      <mesh filename="package://my_arm/meshes/cube.obj"/></geometry></visual></link></robot>)";
  EXPECT_THROW(LoadRobot(elsewhere), Error);
  setenv("TROCAR_PACKAGE_PATH", root.c_str(), 1);
  EXPECT_EQ(LoadRobot(elsewhere).link(0).visuals.at(0).mesh->triangles.size(), 12u);
  unsetenv("TROCAR_PACKAGE_PATH");
}

TEST(LoadRobot, SurrolEcmLoads) {
  const std::string path = test::SharedDataPath("robots/surrol-ecm/ecm.urdf");
  TROCAR_REQUIRE_SHARED_FILE(path);
  const RobotModel model = LoadRobot(path);
  EXPECT_GE(model.num_positions(), 4);
  RobotState state(model);
  std::mt19937 rng(12);
  for (int trial = 0; trial < 100; ++trial) {
    ASSERT_TRUE(ForwardKinematics(model, test::RandomConfiguration(model, &rng), &state).ok());
  }
}

TEST(HeldJoints, AreSetBeforeUseAndRefuseValuesOutsideTheirLimits) {
  const std::string dir = ::testing::TempDir() + "/trocar_held";
  std::filesystem::create_directories(dir);
  const std::string yaml = dir + "/held.yaml";
  {
    std::ofstream out(yaml);
    out << "urdf: " << SourcePath("robots/pa10/pa10.urdf") << "\nheld_joints: [S1]\n";
  }
  const RobotModel model = LoadRobot(yaml);
  EXPECT_EQ(model.num_positions(), 6);
  EXPECT_EQ(model.joint(model.GetJoint("S1")).drive, JointDrive::kHeld);
  RobotState state(model);
  ASSERT_TRUE(kinematics::SetHeldJoint(model, "S1", 0.5, &state).ok());
  ForwardKinematics(model, Eigen::VectorXd::Zero(6), &state);
  const Eigen::Vector3d p = kinematics::FramePose(state, model.tool_frame()).translation();
  EXPECT_NEAR(p.z(), 1.317, 1e-12);
  EXPECT_THROW(kinematics::SetHeldJoint(model, "S1", 4.0, &state), Error);
  EXPECT_THROW(kinematics::SetHeldJoint(model, "S2", 0.1, &state), Error);
  EXPECT_EQ(state.joint_values[model.joint(model.GetJoint("S1")).dof_index], 0.5);
}

}  // namespace
}  // namespace trocar
