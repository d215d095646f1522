#include "kinematics/appearance.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <optional>
#include <random>
#include <regex>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using kinematics::DressRobot;
using robot::RobotModel;
using robot::RobotState;

const std::string kPsm = std::string(TROCAR_SOURCE_DIR) + "/robots/davinci-classic/psm.yaml";
const std::string kEcm = std::string(TROCAR_SOURCE_DIR) + "/robots/davinci-classic/ecm.yaml";
const std::string kCart = std::string(TROCAR_SOURCE_DIR) + "/robots/davinci-classic/cart.yaml";

// Per link, the largest distance over 200 seeded poses other than the fit's between the
// vertices of the link's first worn mesh as the dressing draws it and as the dressing
// description's own kinematics put them. Independent of the dressing's fit: the two bases are
// related by where the first worn mesh is drawn at the first pose.
std::vector<double> Drift(const RobotModel& model, const kinematics::Dressing& dressing) {
  const robot::Appearance& a = model.defaults().appearances.at(0);
  const RobotModel other = robot::LoadRobot(a.urdf);
  std::mt19937 rng(77);
  RobotState ours(model), theirs(other);
  std::vector<double> drift(model.num_links(), 0.0);
  std::optional<Eigen::Isometry3d> X_BO;  // their base in ours
  for (int pose = 0; pose < 200; ++pose) {
    Eigen::VectorXd q = model.neutral_configuration(), p = other.neutral_configuration();
    for (const auto& d : a.joints) {
      const int i = model.joint(model.GetJoint(d.joint)).q_index;
      q[i] = std::uniform_real_distribution<double>(model.lower_limits()[i],
                                                    model.upper_limits()[i])(rng);
      p[other.joint(other.GetJoint(d.drives)).q_index] = d.multiplier * q[i] + d.offset;
    }
    EXPECT_TRUE(kinematics::ForwardKinematics(model, q, &ours).ok());
    EXPECT_TRUE(kinematics::ForwardKinematics(other, p, &theirs).ok());
    for (const auto& wear : a.links) {
      const int l = model.GetLink(wear.link), o = other.GetLink(wear.wears);
      if (dressing.worn[l].empty() || other.link(o).visuals.empty()) continue;
      const robot::Geometry& own =
          other.link(o).visuals[0];  // WeldedVisuals puts the link's own first
      const Eigen::Isometry3d X_B_drawn = ours.X_WL[l] * dressing.worn[l][0].X_LG;
      const Eigen::Isometry3d X_O_own = theirs.X_WL[o] * own.X_LG;
      if (!X_BO) X_BO = X_B_drawn * X_O_own.inverse();
      for (std::size_t v = 0; v < own.mesh->vertices.size(); v += 5) {
        const Eigen::Vector3d c = own.mesh->vertices[v].cwiseProduct(own.mesh_scale);
        drift[l] = std::max(drift[l], (X_B_drawn * c - *X_BO * (X_O_own * c)).norm());
      }
    }
  }
  return drift;
}

TEST(RobotAppearance, TheDaVinciArmsWearTheSurrolMeshesWhichFollowTheirLinksAtEveryPose) {
  TROCAR_REQUIRE_SHARED_FILE(test::SharedDataPath("robots/surrol-psm/psm.urdf"));
  TROCAR_REQUIRE_SHARED_FILE(test::SharedDataPath("robots/surrol-ecm/ecm.urdf"));
  for (const std::string& file : {kPsm, kEcm}) {
    SCOPED_TRACE(file);
    const RobotModel arm = robot::LoadRobot(file);
    const kinematics::Dressing dressing = DressRobot(arm);
    EXPECT_TRUE(dressing.notes.empty());
    const robot::Appearance& a = arm.defaults().appearances.at(0);
    for (const auto& wear : a.links) {
      const int l = arm.GetLink(wear.link);
      const auto& worn = dressing.worn[l];
      EXPECT_TRUE(std::any_of(worn.begin(), worn.end(), [](const robot::Geometry& g) {
        return g.shape == robot::Geometry::Shape::kMesh && g.mesh && !g.mesh->vertices.empty();
      })) << wear.link;
      EXPECT_LE(dressing.drift[l], a.ToleranceOf(wear.link)) << wear.link;
    }
    const std::vector<double> drift = Drift(arm, dressing);
    for (const auto& wear : a.links) {
      const int l = arm.GetLink(wear.link);
      EXPECT_LE(drift[l], a.ToleranceOf(wear.link)) << wear.link;
    }
    for (const char* end :
         {"wrist_pitch_link", "wrist_yaw_link", "jaw_1_link", "jaw_2_link", "scope_link"}) {
      if (arm.FindLink(end) >= 0) {
        EXPECT_LT(drift[arm.GetLink(end)], 0.002) << end;
      }
    }
  }
  // The cart: each arm dressed under its own prefix.
  const RobotModel cart = robot::LoadRobot(kCart);
  const kinematics::Dressing dressing = DressRobot(cart);
  ASSERT_EQ(cart.defaults().appearances.size(), 3u);
  for (const char* link : {"psm1_jaw_1_link", "psm2_pitch_end_link", "ecm_scope_link"}) {
    EXPECT_FALSE(dressing.worn[cart.GetLink(link)].empty()) << link;
  }
  EXPECT_TRUE(dressing.worn[cart.GetLink("ecm_pitch_bottom_link")].empty())
      << "the ECM's bars keep their capsules (ecm.yaml)";
}

// A copy of psm.yaml, with its appearance's file made absolute and `edit` applied, in a folder.
std::string EditedPsm(const std::string& from, const std::string& to) {
  std::ifstream in(kPsm);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const std::string urdf = "../../../shared/data/robots/surrol-psm/psm.urdf";
  text.replace(text.find(urdf), urdf.size(), test::SharedDataPath("robots/surrol-psm/psm.urdf"));
  if (!from.empty()) {
    const auto at = text.find(from);
    EXPECT_NE(at, std::string::npos) << from;
    if (at != std::string::npos) text.replace(at, from.size(), to);
  }
  const std::string dir = test::ScratchPath("appearance");
  std::filesystem::create_directories(dir);
  const std::string path = dir + "/psm.yaml";
  std::ofstream(path) << text;
  return path;
}

TEST(RobotAppearance, AMappingTheModelsDoNotShareIsRefusedNamingTheLinkAndTheDistance) {
  TROCAR_REQUIRE_SHARED_FILE(test::SharedDataPath("robots/surrol-psm/psm.urdf"));
  // The premise: the copy as given dresses.
  EXPECT_NO_THROW(DressRobot(robot::LoadRobot(EditedPsm("", ""))));
  // Each wrong mapping is refused naming a link the wrong joint moves (the worst drift lies
  // downstream of it, where its error adds up).
  struct Case {
    std::string from, to;
    std::vector<std::string> links;
  };
  const std::vector<std::string> tool = {"wrist_pitch_link", "wrist_yaw_link", "jaw_1_link",
                                         "jaw_2_link"};
  auto with = [&](std::vector<std::string> links) {
    links.insert(links.end(), tool.begin(), tool.end());
    return links;
  };
  const std::vector<Case> cases = {
      {"outer_roll: psm_tool_roll_joint",
       "outer_roll: {drives: psm_tool_roll_joint, multiplier: -1}", with({"roll_link"})},
      {"outer_insertion: psm_main_insertion_joint",
       "outer_insertion: {drives: psm_main_insertion_joint, offset: 0.02}",
       with({"insertion_link", "roll_link"})},
      {"outer_wrist_pitch: psm_tool_pitch_joint", "outer_wrist_pitch: psm_tool_yaw_joint",
       with({})},
      {"psm_tool_gripper2_joint, multiplier: -0.5",
       "psm_tool_gripper2_joint, multiplier: 0.5",
       {"jaw_1_link", "jaw_2_link"}},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.to);
    const RobotModel psm = robot::LoadRobot(EditedPsm(c.from, c.to));
    try {
      DressRobot(psm);
      ADD_FAILURE() << "dressed";
    } catch (const Error& e) {
      const std::string m = e.what();
      std::smatch named;
      ASSERT_TRUE(
          std::regex_search(m, named, std::regex("appearance\\.links\\.([a-z0-9_]+): its mesh")))
          << m;
      EXPECT_NE(std::find(c.links.begin(), c.links.end(), named[1].str()), c.links.end()) << m;
      EXPECT_TRUE(std::regex_search(m, std::regex("drawn [0-9.]+ mm from where"))) << m;
    }
  }
}

TEST(RobotAppearance, BadAppearanceFieldsAreNamedAndAMissingFileDrawsTheOwnShapes) {
  TROCAR_REQUIRE_SHARED_FILE(test::SharedDataPath("robots/surrol-psm/psm.urdf"));
  struct Case {
    std::string from, to, says;
  };
  const std::vector<Case> load_errors = {
      {"tolerances: {", "tolerance: 0\n  tolerances: {", "appearance.tolerance"},
      {"pitch_top_link: 0.0", "pitch_top_link: -0.0", "appearance.tolerances.pitch_top_link"},
      {"tolerances: {", "tolerances: {jaw_link: 0.01, ", "'jaw_link' wears nothing"},
      {"psm_tool_gripper2_joint, multiplier: -0.5", "psm_tool_gripper2_joint, multiplier: 0",
       "appearance.joints.jaw.multiplier"},
      {"rcm_base: psm_base_link", "no_such_link: psm_base_link", "no link named 'no_such_link'"},
      {"outer_yaw: psm_yaw_joint", "no_such_joint: psm_yaw_joint",
       "no joint named 'no_such_joint'"},
      {"tolerances: {", "colour: red\n  tolerances: {", "colour"},
  };
  for (const Case& c : load_errors) {
    SCOPED_TRACE(c.to);
    try {
      robot::LoadRobot(EditedPsm(c.from, c.to));
      ADD_FAILURE() << "loaded";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(c.says), std::string::npos) << e.what();
    }
  }
  const std::vector<Case> dress_errors = {
      {"yaw_link: psm_yaw_link", "yaw_link: psm_no_link",
       "appearance.links.yaw_link: 'psm_no_link' is no link"},
      {"outer_yaw: psm_yaw_joint", "outer_yaw: psm_no_joint",
       "appearance.joints.outer_yaw: 'psm_no_joint' is no joint"},
      {"outer_yaw: psm_yaw_joint", "outer_yaw: psm_pitch_end_joint",
       "'psm_pitch_end_joint' is not an active joint"},
      {"outer_yaw: psm_yaw_joint", "pitch_front: psm_yaw_joint",
       "appearance.joints.pitch_front: not an active joint"},
  };
  for (const Case& c : dress_errors) {
    SCOPED_TRACE(c.to);
    try {
      DressRobot(robot::LoadRobot(EditedPsm(c.from, c.to)));
      ADD_FAILURE() << "dressed";
    } catch (const Error& e) {
      EXPECT_NE(std::string(e.what()).find(c.says), std::string::npos) << e.what();
    }
  }
  // Without the dressing's file the robot loads and dresses nothing, saying why.
  const std::string path =
      EditedPsm(test::SharedDataPath("robots/surrol-psm/psm.urdf"), "/nonexistent/psm.urdf");
  const RobotModel psm = robot::LoadRobot(path);
  const kinematics::Dressing dressing = DressRobot(psm);
  EXPECT_FALSE(dressing.any());
  ASSERT_EQ(dressing.notes.size(), 1u);
  EXPECT_NE(dressing.notes[0].find("/nonexistent/psm.urdf not found"), std::string::npos)
      << dressing.notes[0];
}

}  // namespace
}  // namespace trocar
