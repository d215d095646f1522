// Bad input gets a clear error naming the file, element and value: never a crash, never a
// silently wrong model.
#include <cmath>
#include <filesystem>
#include <fstream>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using robot::LoadRobot;

class BadInput : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = ::testing::TempDir() + "/trocar_bad_input_" +
           ::testing::UnitTest::GetInstance()->current_test_info()->name();
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
  }
  std::string Write(const std::string& name, const std::string& text) {
    const std::string path = dir_ + "/" + name;
    std::ofstream(path) << text;
    return path;
  }
  // Loads `path` and returns the error message (fails the test if nothing is thrown).
  std::string LoadError(const std::string& path) {
    try {
      LoadRobot(path);
    } catch (const Error& e) {
      return e.what();
    }
    ADD_FAILURE() << "loading " << path << " did not fail";
    return "";
  }
  std::string dir_;
};

#define EXPECT_CONTAINS(text, part) \
  EXPECT_NE(std::string(text).find(part), std::string::npos) << "message: " << (text)

const char* kTwoLinkUrdf = R"(<?xml version="1.0"?>
<robot name="two">
  <link name="a"/><link name="b"/>
  <joint name="j1" type="revolute"><parent link="a"/><child link="b"/>
    <axis xyz="0 0 1"/><limit lower="%LOWER%" upper="0.9" velocity="1" effort="1"/></joint>
</robot>)";

std::string WithLower(const std::string& lower) {
  std::string text = kTwoLinkUrdf;
  text.replace(text.find("%LOWER%"), 7, lower);
  return text;
}

TEST_F(BadInput, MissingFileIsNamed) {
  EXPECT_EQ(LoadError(dir_ + "/nothing.urdf"), dir_ + "/nothing.urdf: robot description not found");
}

TEST_F(BadInput, MalformedUrdfNamesTheFileAndTheParserReason) {
  const std::string path = Write("broken.urdf", "<robot name='x'><link name='a'></robot>");
  const std::string message = LoadError(path);
  EXPECT_CONTAINS(message, path);
  EXPECT_CONTAINS(message, "not a valid URDF");
}

TEST_F(BadInput, LowerLimitAboveUpperNamesJointAndValues) {
  const std::string path = Write("limits.urdf", WithLower("1.2"));
  EXPECT_EQ(LoadError(path), path + ": joint 'j1': lower limit 1.2 > upper limit 0.9");
}

TEST_F(BadInput, NanInUrdfIsRefused) {
  const std::string path = Write("nan.urdf", WithLower("nan"));
  const std::string message = LoadError(path);
  EXPECT_CONTAINS(message, path);
  EXPECT_CONTAINS(message, "j1");
}

TEST_F(BadInput, MissingMeshNamesLinkAndFile) {
  const std::string path = Write("mesh.urdf", R"(<robot name="m"><link name="a"><visual>
      <geometry><mesh filename="meshes/none.stl"/></geometry></visual></link></robot>)");
  const std::string message = LoadError(path);
  EXPECT_CONTAINS(message, path + ": link 'a' visual 0: mesh file 'meshes/none.stl' not found");
}

TEST_F(BadInput, UnknownPackageIsNamed) {
  const std::string path = Write("pkg.urdf", R"(<robot name="m"><link name="a"><visual>
      <geometry><mesh filename="package://no_such_pkg/x.stl"/></geometry></visual></link></robot>)");
  EXPECT_CONTAINS(LoadError(path), "package 'no_such_pkg' not found");
}

TEST_F(BadInput, MeshWithNonFiniteVertexIsRefused) {
  Write("bad.obj", "v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n");
  const std::string path = Write("nanmesh.urdf", R"(<robot name="m"><link name="a"><visual>
      <geometry><mesh filename="bad.obj"/></geometry></visual></link></robot>)");
  const std::string message = LoadError(path);
  EXPECT_CONTAINS(message, "link 'a' visual 0");
  EXPECT_CONTAINS(message, "bad.obj");
}

TEST_F(BadInput, EmptyMeshIsRefused) {
  Write("empty.stl", "solid empty\nendsolid empty\n");
  const std::string path = Write("emptymesh.urdf", R"(<robot name="m"><link name="a"><collision>
      <geometry><mesh filename="empty.stl"/></geometry></collision></link></robot>)");
  const std::string message = LoadError(path);
  EXPECT_CONTAINS(message, "link 'a' collision 0");
  EXPECT_CONTAINS(message, "empty.stl");
}

TEST_F(BadInput, FloatingJointIsRefused) {
  const std::string path = Write("float.urdf", R"(<robot name="f"><link name="a"/><link name="b"/>
      <joint name="free" type="floating"><parent link="a"/><child link="b"/></joint></robot>)");
  EXPECT_CONTAINS(LoadError(path), "joint 'free': joint type");
}

TEST_F(BadInput, UnknownMimicMasterIsNamed) {
  const std::string path = Write("mimic.urdf", R"(<robot name="m"><link name="a"/><link name="b"/>
      <joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/><mimic joint="ghost"/></joint></robot>)");
  EXPECT_CONTAINS(LoadError(path), "joint 'j' mimic: no joint named 'ghost'");
}

TEST_F(BadInput, AMimicCycleIsRefusedNamingTheJoints) {
  const std::string path = Write("cycle.urdf", R"(<robot name="m"><link name="a"/><link name="b"/>
      <link name="c"/><link name="d"/>
      <joint name="drive" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
      <joint name="j1" type="revolute"><parent link="b"/><child link="c"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/><mimic joint="j2"/></joint>
      <joint name="j2" type="revolute"><parent link="c"/><child link="d"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/><mimic joint="j1"/></joint></robot>)");
  const std::string message = LoadError(path);
  EXPECT_EQ(message, path + ": joints depend on each other in a cycle: j1 -> j2 -> j1");
}

TEST_F(BadInput, AClosedLoopTheSidecarDoesNotDeclareIsRefused) {
  // Link c hangs from two joints: a loop in the URDF's tree, which trocar models only as a
  // declared four-bar closure.
  const std::string path = Write("loop.urdf", R"(<robot name="l"><link name="a"/><link name="b"/>
      <link name="c"/>
      <joint name="ab" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
      <joint name="bc" type="revolute"><parent link="b"/><child link="c"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
      <joint name="ac" type="revolute"><parent link="a"/><child link="c"/><axis xyz="0 0 1"/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/></joint></robot>)");
  EXPECT_EQ(LoadError(path), path + ": joint 'bc': link 'c' already has parent joint 'ac' (a "
                                    "kinematic tree; close loops with a four-bar closure)");
}

TEST_F(BadInput, AHomeOutsideTheLimitsNamesTheJointAndTheValue) {
  const std::string urdf = Write("home.urdf", WithLower("-0.5"));
  const std::string path = Write("home.yaml", "urdf: " + urdf + "\nhome: [1.5]\n");
  const std::string message = LoadError(path);
  EXPECT_CONTAINS(message, "home: joint 'j1' value 1.5 is outside its limits [-0.5, 0.9]");
}

TEST_F(BadInput, AnInfiniteOrNanVelocityLimitIsNamed) {
  std::string text = WithLower("-0.5");
  text.replace(text.find("velocity=\"1\""), 12, "velocity=\"nan\"");
  const std::string path = Write("velocity.urdf", text);
  const std::string message = LoadError(path);
  EXPECT_CONTAINS(message, path);
  EXPECT_CONTAINS(message, "j1");
}

// TinyXML (under urdfdom) reads past the end of a document that stops inside a construct (an
// ASan heap over-read found by fuzzing, tests/fuzz/regressions/urdf): trocar refuses such a
// document first, naming the line where the unfinished construct starts.
TEST_F(BadInput, ADocumentEndingInsideATagOrCommentIsRefusedBeforeTheXmlParser) {
  const std::string head = "<robot name=\"x\"><link name=\"a\"/>\n";
  struct Case {
    const char* tail;
    const char* expected;
  };
  for (const Case& c : {
           Case{"<link name=\"b", ": not a valid URDF: the tag '<link name=\"b' is never closed (an "
                                  "attribute value is still open) (the file ends first)"},
           Case{"<link name=\"b\"", ": not a valid URDF: the tag '<link name=\"b\"' is never closed (the "
                                     "file ends first)"},
           Case{"<!-- a comment", ": not a valid URDF: '<!-- a co' is never closed by '-->' (the file "
                                  "ends first)"},
           Case{"<![CDATA[ data", ": not a valid URDF: '<![CDATA[' is never closed by ']]>' (the file "
                                  "ends first)"},
       }) {
    const std::string path = Write("truncated.urdf", head + c.tail);
    EXPECT_EQ(LoadError(path), path + ":2" + c.expected);
  }
  const std::string finding =
      test::SourcePath("tests/fuzz/regressions/urdf/tinyxml-overread-unclosed-attribute.urdf");
  EXPECT_CONTAINS(LoadError(finding), "not a valid URDF");
}

TEST_F(BadInput, YamlSyntaxErrorGivesLineAndColumn) {
  const std::string path = Write("syntax.yaml", "name: x\ndh: [unclosed\n");
  EXPECT_CONTAINS(LoadError(path), path + ":3:1: YAML syntax error");
}

TEST_F(BadInput, DhLimitsOutOfOrderGiveLineAndField) {
  const std::string path = Write("dh.yaml", R"(dh:
  convention: modified
  joints:
    - {type: revolute, limits: {lower: 1, upper: -1}}
)");
  EXPECT_EQ(LoadError(path),
            path + ":4:32: dh.joints[0].limits: lower limit 1 > upper limit -1");
}

TEST_F(BadInput, DhTypoInFieldNameIsReported) {
  const std::string path = Write("typo.yaml", R"(dh:
  convention: modified
  joints:
    - {type: revolute, alpah: 0.5}
)");
  EXPECT_CONTAINS(LoadError(path), "dh.joints[0]: unknown field 'alpah'");
}

TEST_F(BadInput, DhNonNumberIsReported) {
  const std::string path = Write("nan.yaml", R"(dh:
  convention: standard
  joints:
    - {type: revolute, d: abc}
)");
  EXPECT_CONTAINS(LoadError(path), "dh.joints[0].d: expected a number (or pi/2, 90 deg), got 'abc'");
}

TEST_F(BadInput, DhUnknownConventionIsReported) {
  const std::string path = Write("conv.yaml", "dh:\n  convention: craig\n  joints: []\n");
  EXPECT_CONTAINS(LoadError(path), "dh.convention: 'craig' (expected standard or modified)");
}

TEST_F(BadInput, SidecarUnknownJointIsNamedWithItsLine) {
  const std::string path = Write("side.yaml", "urdf: " + test::SourcePath("robots/pa10/pa10.urdf") +
                                                  "\nactive_joints: [S1, S9]\n");
  EXPECT_CONTAINS(LoadError(path), path + ":2:21: active_joints[1]: no joint named 'S9'");
}

TEST_F(BadInput, TwoRootLinksAreReported) {
  const std::string path = Write("roots.urdf", R"(<robot name="r"><link name="a"/><link name="b"/>
      <link name="c"/><joint name="j" type="fixed"><parent link="a"/><child link="b"/></joint>
      </robot>)");
  // urdfdom itself refuses a model with two roots; either way the file is named.
  EXPECT_CONTAINS(LoadError(path), path);
}

// A parallelogram URDF whose rocker axis can be tilted, with its closure in a sidecar.
std::string ParallelogramUrdf(const std::string& rocker_axis) {
  return R"(<robot name="p"><link name="g"/><link name="crank"/><link name="coupler"/>
    <link name="rocker"/>
    <joint name="d" type="revolute"><parent link="g"/><child link="crank"/><axis xyz="0 1 0"/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
    <joint name="r" type="revolute"><parent link="g"/><child link="rocker"/>
      <origin xyz="0.1 0 0"/><axis xyz=")" + rocker_axis + R"("/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/></joint>
    <joint name="c" type="revolute"><parent link="crank"/><child link="coupler"/>
      <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/>
      <limit lower="-1" upper="1" velocity="1" effort="1"/></joint></robot>)";
}

TEST_F(BadInput, FourBarWithNonParallelAxesIsRefused) {
  const std::string urdf = Write("tilted.urdf", ParallelogramUrdf("0.1 1 0"));
  Write("tilted.trocar.yaml",
        "closures: [{name: loop, type: four_bar, driver: d, coupler: c, rocker: r, "
        "cut_point: [0.1, 0, 0]}]\n");
  const std::string message = LoadError(urdf);
  EXPECT_CONTAINS(message, "closure 'loop': axis of joint 'r' is 5.71");
  EXPECT_CONTAINS(message, "four parallel axes");
}

TEST_F(BadInput, FourBarNotAssembledAtZeroIsRefused) {
  const std::string urdf = Write("open.urdf", ParallelogramUrdf("0 1 0"));
  Write("open.trocar.yaml",
        "closures: [{name: loop, type: four_bar, driver: d, coupler: c, rocker: r, "
        "cut_point: [0.1, 0, 0], cut_point_rocker: [0, 0, 0.25]}]\n");
  EXPECT_CONTAINS(LoadError(urdf), "closure 'loop': not assembled at the zero configuration");
}

TEST_F(BadInput, FourBarWithPrismaticJointIsRefused) {
  std::string text = ParallelogramUrdf("0 1 0");
  text.replace(text.find("name=\"r\" type=\"revolute\""), 24, "name=\"r\" type=\"prismatic\"");
  const std::string urdf = Write("prism.urdf", text);
  Write("prism.trocar.yaml",
        "closures: [{name: loop, type: four_bar, driver: d, coupler: c, rocker: r, "
        "cut_point: [0.1, 0, 0]}]\n");
  EXPECT_CONTAINS(LoadError(urdf), "joint 'r' must be revolute, is prismatic");
}

TEST_F(BadInput, IncludeCycleIsRefused) {
  const std::string a = Write("a.yaml", "include: [{file: b.yaml}]\n");
  Write("b.yaml", "include: [{file: a.yaml}]\n");
  EXPECT_CONTAINS(LoadError(a), "included from itself (include cycle)");
}

TEST_F(BadInput, IncludeUnderAnUnknownLinkIsNamed) {
  Write("arm.yaml", "links: [{name: a}, {name: b}]\n"
                    "joints: [{name: j, type: revolute, parent: a, child: b}]\n");
  const std::string cart = Write("cart.yaml", "links: [{name: cart}]\n"
                                              "include: [{file: arm.yaml, prefix: x_, parent: kart}]\n");
  EXPECT_CONTAINS(LoadError(cart), "include[0]: " + cart + ": include of '");
  EXPECT_CONTAINS(LoadError(cart), "no parent link 'kart'");
}

TEST_F(BadInput, IncludingTheSameArmTwiceWithoutPrefixesClashes) {
  Write("arm.yaml", "links: [{name: a}, {name: b}]\n"
                    "joints: [{name: j, type: revolute, parent: a, child: b}]\n");
  const std::string cart = Write("twice.yaml", "links: [{name: cart}]\ninclude:\n"
                                               "  - {file: arm.yaml, parent: cart}\n"
                                               "  - {file: arm.yaml, parent: cart}\n");
  EXPECT_CONTAINS(LoadError(cart), "link 'a' is defined twice");
}

TEST_F(BadInput, TreeJointWithUnknownLinkGivesLine) {
  const std::string path = Write("tree.yaml", "links: [{name: a}]\n"
                                              "joints:\n  - {name: j, type: revolute, parent: a, child: zz}\n");
  EXPECT_CONTAINS(LoadError(path), path + ":3:49: joints[0].child: no link named 'zz'");
}

TEST_F(BadInput, TreeJointTypeIsChecked) {
  const std::string path = Write("type.yaml", "links: [{name: a}, {name: b}]\n"
                                              "joints: [{name: j, type: ball, parent: a, child: b}]\n");
  EXPECT_CONTAINS(LoadError(path), "joints[0].type: joint type 'ball'");
}

TEST(BadConfiguration, NanAndWrongSizeNameTheJoint) {
  const auto model = LoadRobot(test::SourcePath("robots/pa10/pa10.yaml"));
  robot::RobotState state(model);
  Eigen::VectorXd q = Eigen::VectorXd::Zero(7);
  q[3] = std::nan("");
  try {
    kinematics::SetConfiguration(model, q, &state);
    FAIL() << "NaN accepted";
  } catch (const Error& e) {
    EXPECT_EQ(std::string(e.what()),
              "robot 'pa10': configuration value 3 (joint 'E1') is nan, expected a finite number");
  }
  EXPECT_THROW(kinematics::SetConfiguration(model, Eigen::VectorXd::Zero(6), &state), Error);
  EXPECT_EQ(state.q, model.neutral_configuration());  // untouched
}

}  // namespace
}  // namespace trocar
