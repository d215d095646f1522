#include <gtest/gtest.h>

#include <filesystem>
#include <random>
#include <thread>

#include "collision/collision_world.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "patient/patient_model.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar {
namespace {

using collision::Bit;
using collision::CollisionChecker;
using collision::CollisionWorld;
using collision::PairClass;

// An axis-aligned box as a closed triangle mesh (12 triangles, outward).
TriangleMesh BoxMesh(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
  TriangleMesh m;
  for (int k = 0; k < 8; ++k) {
    m.vertices.emplace_back(k & 1 ? hi.x() : lo.x(), k & 2 ? hi.y() : lo.y(),
                            k & 4 ? hi.z() : lo.z());
  }
  const int faces[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& f : faces) {
    m.triangles.emplace_back(f[0], f[1], f[2]);
    m.triangles.emplace_back(f[0], f[2], f[3]);
  }
  return m;
}

// An ellipsoid surface (UV sphere) with about 2·rings·segments triangles.
TriangleMesh Ellipsoid(const Eigen::Vector3d& centre, const Eigen::Vector3d& semi, int rings,
                       int segments) {
  return test::UvSphere(rings, segments, [&](int r, int s) {
    const double phi = M_PI * r / rings, th = 2 * M_PI * s / segments;
    return Eigen::Vector3d(centre + Eigen::Vector3d(semi.x() * std::sin(phi) * std::cos(th),
                                                    semi.y() * std::sin(phi) * std::sin(th),
                                                    semi.z() * std::cos(phi)));
  });
}

std::shared_ptr<const robot::RobotModel> RobotFromYaml(const std::string& name,
                                                       const std::string& yaml) {
  const std::string path = ::testing::TempDir() + "/trocar_collision_" + name + ".yaml";
  WriteFileAtomically(path, yaml);
  return std::make_shared<const robot::RobotModel>(robot::LoadRobot(path));
}

// Two "probes" A and B, each a point moved by three prismatic joints (x, y, z) carrying one shape.
std::shared_ptr<const robot::RobotModel> Probes(const std::string& shape_a,
                                                const std::string& shape_b) {
  std::ostringstream y;
  y << "name: probes\nlinks:\n  - name: base\n";
  for (const char* p : {"a", "b"}) {
    y << "  - name: " << p << "_x\n  - name: " << p << "_y\n  - name: " << p
      << "_tip\n    collision: [" << (p[0] == 'a' ? shape_a : shape_b) << "]\n";
  }
  y << "joints:\n";
  for (const char* p : {"a", "b"}) {
    const std::string s(p);
    y << "  - {name: " << s << "_px, type: prismatic, parent: base, child: " << s
      << "_x, axis: [1, 0, 0], limits: {lower: -2, upper: 2}}\n"
      << "  - {name: " << s << "_py, type: prismatic, parent: " << s << "_x, child: " << s
      << "_y, axis: [0, 1, 0], limits: {lower: -2, upper: 2}}\n"
      << "  - {name: " << s << "_pz, type: prismatic, parent: " << s << "_y, child: " << s
      << "_tip, axis: [0, 0, 1], limits: {lower: -2, upper: 2}}\n";
  }
  return RobotFromYaml("probes", y.str());
}

robot::RobotState PlaceProbes(const robot::RobotModel& model, const Eigen::Vector3d& a,
                              const Eigen::Vector3d& b) {
  robot::RobotState state(model);
  Eigen::VectorXd q(6);
  q << a, b;
  EXPECT_TRUE(kinematics::ForwardKinematics(model, q, &state).ok());
  return state;
}

double PointBoxDistance(const Eigen::Vector3d& p, const Eigen::Vector3d& lo,
                        const Eigen::Vector3d& hi) {
  return (p.cwiseMax(lo).cwiseMin(hi) - p).norm();
}

TEST(CollisionWorld, PrimitivesAndMeshesAtKnownDistances) {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  const Eigen::Vector3d lo(-0.05, -0.04, -0.03), hi(0.05, 0.04, 0.03);
  collision::CollisionWorld::FixedMesh box{"block", BoxMesh(lo, hi), Eigen::Isometry3d::Identity(),
                                           false, false};
  struct Case {
    std::string a, b;
  };
  // Capsules along z (the probes only translate), so every answer has a closed form.
  const auto spheres = Probes("{shape: sphere, radius: 0.02}", "{shape: sphere, radius: 0.035}");
  const auto capsules = Probes("{shape: capsule, radius: 0.01, length: 0.12}",
                               "{shape: capsule, radius: 0.015, length: 0.08}");
  const auto boxes =
      Probes("{shape: box, size: [0.04, 0.06, 0.02]}", "{shape: sphere, radius: 0.01}");
  int checked = 0;
  for (const auto& model : {spheres, capsules, boxes}) {
    const auto world = CollisionWorld::Build({box}, model);
    CollisionChecker checker(world);
    const int block = world->FindBody("block");
    for (int trial = 0; trial < 200; ++trial) {
      const Eigen::Vector3d pa(u(rng), u(rng), u(rng)), pb(u(rng), u(rng), u(rng));
      checker.SetRobotState(PlaceProbes(*model, pa, pb));
      // Expected arm–arm and arm–block distances.
      double arm_arm = 0, a_block = 0;
      if (model == spheres) {
        arm_arm = (pa - pb).norm() - 0.055;
        a_block = PointBoxDistance(pa, lo, hi) - 0.02;
      } else if (model == capsules) {
        const Eigen::Vector2d lateral = (pa - pb).head<2>();
        const double gap = std::max(0.0, std::abs(pa.z() - pb.z()) - 0.5 * (0.12 + 0.08));
        arm_arm = std::hypot(lateral.norm(), gap) - 0.025;
        // Capsule A vs the box: the segment's nearest point is where z is clamped into the box.
        const double z = std::clamp(hi.z(), pa.z() - 0.06, pa.z() + 0.06);
        const double zl = std::clamp(lo.z(), pa.z() - 0.06, pa.z() + 0.06);
        a_block = std::min(PointBoxDistance({pa.x(), pa.y(), z}, lo, hi),
                           PointBoxDistance({pa.x(), pa.y(), zl}, lo, hi)) -
                  0.01;
        if (pa.z() - 0.06 <= hi.z() && pa.z() + 0.06 >= lo.z()) {
          a_block =
              PointBoxDistance({pa.x(), pa.y(), std::clamp(pa.z(), lo.z(), hi.z())}, lo, hi) - 0.01;
        }
      } else {
        const Eigen::Vector3d half(0.02, 0.03, 0.01);
        arm_arm = PointBoxDistance(pb, pa - half, pa + half) - 0.01;
        a_block = (((pa - half) - hi).cwiseMax(lo - (pa + half)).cwiseMax(0.0)).norm();
      }
      const auto aa = checker.MinimumDistance(Bit(PairClass::kArmArm));
      const auto ab = checker.MinimumDistance(Bit(PairClass::kArmTable));
      if (arm_arm > 1e-4) {
        ++checked;
        ASSERT_TRUE(aa.valid());
        EXPECT_NEAR(aa.distance, arm_arm, 1e-6)
            << "trial " << trial << " " << pa.transpose() << " | " << pb.transpose();
        EXPECT_NEAR((aa.p_W_a - aa.p_W_b).norm(), aa.distance, 1e-6);
        EXPECT_FALSE(checker.InCollision(Bit(PairClass::kArmArm)));
      } else if (arm_arm < -1e-4) {
        EXPECT_EQ(aa.distance, 0.0);
        EXPECT_TRUE(checker.InCollision(Bit(PairClass::kArmArm)));
      }
      // The block is A's or B's nearest fixed body; check A's alone when it is nearer.
      if (a_block > 1e-4 && ab.valid() && ab.a == world->FindBody("a_tip")) {
        ASSERT_EQ(ab.b, block);
        EXPECT_NEAR(ab.distance, a_block, 1e-6) << "trial " << trial << " " << pa.transpose();
      }
    }
  }
  EXPECT_GT(checked, 300);
}

// A body (a box of "skin" with its top at z = 0), a rib under it, and an instrument whose shaft
// pivots about an RCM at the port (0, 0, 0).
struct PortScene {
  std::shared_ptr<const robot::RobotModel> model;
  std::shared_ptr<const CollisionWorld> world;
};

// An instrument through a port: a slide along x, a tilt about y at the RCM (the holder), a 20 cm
// shaft of radius 4 mm inserted along -z; with `holder_box`, the holder drawn as a 5 cm box 10 cm
// above the RCM (a link that is not the instrument).
std::shared_ptr<const robot::RobotModel> ShaftThroughPort(const std::string& name,
                                                          bool holder_box) {
  return RobotFromYaml(
      name, std::string(R"(name: instrument
links:
  - name: base
  - name: slide
  - name: holder
)") +
                (holder_box
                     ? "    collision: [{shape: box, size: [0.05, 0.05, 0.05], xyz: [0, 0, 0.1]}]\n"
                     : "") +
                R"(  - name: shaft
    collision: [{shape: capsule, radius: 0.004, length: 0.2, xyz: [0, 0, -0.05]}]
joints:
  - {name: move_x, type: prismatic, parent: base, child: slide, axis: [1, 0, 0], limits: {lower: -1, upper: 1}}
  - {name: tilt, type: revolute, parent: slide, child: holder, axis: [0, 1, 0], limits: {lower: -1.5, upper: 1.5}}
  - {name: insertion, type: prismatic, parent: holder, child: shaft, axis: [0, 0, -1], limits: {lower: 0, upper: 0.1}}
rcm: {link: holder}
)");
}

PortScene MakePortScene(double port_radius = 0.015) {
  PortScene s;
  s.model = ShaftThroughPort("port", true);
  collision::WorldOptions options;
  options.port_radius = port_radius;
  std::vector<CollisionWorld::FixedMesh> meshes = {
      {"skin", BoxMesh({-0.2, -0.2, -0.3}, {0.2, 0.2, 0.0}), Eigen::Isometry3d::Identity(), true,
       true},
      {"ribs", BoxMesh({0.02, -0.1, -0.05}, {0.04, 0.1, -0.03}), Eigen::Isometry3d::Identity(),
       false, true}};
  s.world = CollisionWorld::Build(meshes, s.model, options);
  return s;
}

robot::RobotState Pose(const robot::RobotModel& model, double x, double tilt, double insertion) {
  robot::RobotState state(model);
  EXPECT_TRUE(
      kinematics::ForwardKinematics(model, Eigen::Vector3d(x, tilt, insertion), &state).ok());
  return state;
}

TEST(CollisionWorld, AShaftThroughItsPortIsFreeAndTheSameShaftHittingARibCollides) {
  const PortScene s = MakePortScene();
  ASSERT_EQ(s.world->ports().size(), 1u);
  EXPECT_EQ(s.world->ports()[0].frame, "rcm");
  const int shaft = s.world->FindBody("shaft"), ribs = s.world->FindBody("ribs"),
            skin = s.world->FindBody("skin");
  EXPECT_EQ(s.world->bodies()[shaft].port, 0);
  EXPECT_EQ(s.world->bodies()[s.world->FindBody("holder")].port, -1);
  CollisionChecker checker(s.world);

  // Straight down through the port, inserted: passes between the ribs.
  checker.SetRobotState(Pose(*s.model, 0, 0, 0.05));
  EXPECT_TRUE(checker.port_position(0).isZero(1e-12));
  auto report = checker.Check();
  EXPECT_FALSE(report.collision);
  EXPECT_EQ(report.port_contacts_allowed, 1);
  EXPECT_FALSE(checker.InCollision());
  // The rib's clearance: 0.02 − 0.004 to the shaft's side.
  const auto clear = checker.MinimumDistance(Bit(PairClass::kInstrumentPatient));
  EXPECT_EQ(clear.b, ribs);
  EXPECT_NEAR(clear.distance, 0.016, 1e-6);

  // Tilted 40° about y: the shaft runs into the rib 3–5 cm deep.
  checker.SetRobotState(Pose(*s.model, 0, -0.7, 0.05));
  report = checker.Check();
  ASSERT_TRUE(report.collision);
  ASSERT_EQ(report.contacts.size(), 1u);
  EXPECT_EQ(report.contacts[0].a, shaft);
  EXPECT_EQ(report.contacts[0].b, ribs);
  EXPECT_EQ(report.contacts[0].cls, PairClass::kInstrumentPatient);
  EXPECT_TRUE(checker.InCollision(Bit(PairClass::kInstrumentPatient)));
  EXPECT_FALSE(checker.InCollision(Bit(PairClass::kArmPatient)));

  // The same shaft crossing the skin 5 cm from where its port is: a collision with the skin.
  checker.SetRobotState(Pose(*s.model, 0, 0, 0.05));
  checker.SetPortPosition(0, Eigen::Vector3d(0.05, 0, 0));
  report = checker.Check();
  ASSERT_TRUE(report.collision);
  EXPECT_EQ(report.contacts[0].b, skin);
  EXPECT_LT(report.contacts[0].p_W.head<2>().norm(), 0.01);
  // A radius wide enough to cover it makes it free again.
  const PortScene wide = MakePortScene(0.08);
  CollisionChecker wide_checker(wide.world);
  wide_checker.SetRobotState(Pose(*wide.model, 0, 0, 0.05));
  wide_checker.SetPortPosition(0, Eigen::Vector3d(0.05, 0, 0));
  EXPECT_FALSE(wide_checker.InCollision());

  // A link that is not the instrument (the holder) touching the skin counts at the port too.
  checker.SetRobotState(Pose(*s.model, 0, 1.5, 0.0));
  report = checker.Check();
  bool holder_hit = false;
  for (const auto& c : report.contacts)
    holder_hit |= c.a == s.world->FindBody("holder") && c.cls == PairClass::kArmPatient;
  EXPECT_TRUE(holder_hit);
}

// The contact rule at the target (docs/decisions.md, "contact rules"): an instrument's wrist and
// jaws (its distal links: within 2 cm of its deepest link at rest; not its shaft) may touch an
// organ within the work site's radius of the target they work on; anywhere else, or with no work
// site, or with the shaft, the same contact is a collision. The organ's top is 15 cm down, the
// target on it below the port.
TEST(CollisionWorld, TheJawsMayTouchTheOrganAtTheirWorkSiteAndNowhereElse) {
  const auto model = RobotFromYaml("wrist", R"(name: instrument
links:
  - name: base
  - name: slide
  - name: holder
  - name: shaft
    collision: [{shape: capsule, radius: 0.004, length: 0.1, xyz: [0, 0, -0.05]}]
  - name: wrist
    collision: [{shape: capsule, radius: 0.003, length: 0.008, xyz: [0, 0, -0.004]}]
  - name: jaw
    collision: [{shape: capsule, radius: 0.002, length: 0.006, xyz: [0, 0, -0.003]}]
joints:
  - {name: move_x, type: prismatic, parent: base, child: slide, axis: [1, 0, 0], limits: {lower: -1, upper: 1}}
  - {name: tilt, type: revolute, parent: slide, child: holder, axis: [0, 1, 0], limits: {lower: -1.5, upper: 1.5}}
  - {name: insertion, type: prismatic, parent: holder, child: shaft, axis: [0, 0, -1], limits: {lower: 0, upper: 0.1}}
  - {name: wrist_pitch, type: revolute, parent: shaft, child: wrist, origin: {xyz: [0, 0, -0.1]}, axis: [0, 1, 0], limits: {lower: -1.5, upper: 1.5}}
  - {name: grip, type: revolute, parent: wrist, child: jaw, origin: {xyz: [0, 0, -0.008]}, axis: [0, 1, 0], limits: {lower: -1, upper: 1}}
rcm: {link: holder}
)");
  std::vector<CollisionWorld::FixedMesh> meshes = {
      {"skin", BoxMesh({-0.2, -0.2, -0.3}, {0.2, 0.2, 0.0}), Eigen::Isometry3d::Identity(), true,
       true},
      {"heart", BoxMesh({-0.1, -0.1, -0.25}, {0.1, 0.1, -0.15}), Eigen::Isometry3d::Identity(),
       false, true}};
  const auto world = CollisionWorld::Build(meshes, model);
  const int shaft = world->FindBody("shaft"), wrist = world->FindBody("wrist"),
            jaw = world->FindBody("jaw"), heart = world->FindBody("heart");
  EXPECT_FALSE(world->bodies()[shaft].distal);
  EXPECT_TRUE(world->bodies()[wrist].distal);
  EXPECT_TRUE(world->bodies()[jaw].distal);
  CollisionChecker checker(world);
  auto pose = [&](double insertion) {
    robot::RobotState state(*model);
    Eigen::VectorXd q(5);
    q << 0, 0, insertion, 0, 0;
    EXPECT_TRUE(kinematics::ForwardKinematics(*model, q, &state).ok());
    return state;
  };
  const Eigen::Vector3d target(0, 0, -0.15);
  // The jaws 2 mm into the organ at the target.
  checker.SetRobotState(pose(0.036));
  auto report = checker.Check();
  ASSERT_TRUE(report.collision);  // no work site: a collision
  EXPECT_EQ(report.contacts[0].a, jaw);
  EXPECT_EQ(report.contacts[0].b, heart);
  checker.SetWorkSite(0, target, 0.015);
  report = checker.Check();
  EXPECT_FALSE(report.collision);
  EXPECT_EQ(report.work_contacts_allowed, 1);
  EXPECT_FALSE(checker.InCollision());
  // Its distance to the organ at the work site is not a clearance (zero there by design).
  const auto clear = checker.MinimumDistance(Bit(PairClass::kInstrumentPatient));
  EXPECT_TRUE(!clear.valid() || (clear.a != jaw && clear.a != wrist)) << clear.a;
  // The work site 5 cm away: the same contact is a collision.
  checker.SetWorkSite(0, target + Eigen::Vector3d(0.05, 0, 0), 0.015);
  EXPECT_TRUE(checker.InCollision());
  // Cleared: a collision again.
  checker.SetWorkSite(0, target, 0.015);
  checker.ClearWorkSites();
  EXPECT_TRUE(checker.InCollision());
  // Deeper: the shaft reaches the organ too; the shaft may not, whatever the work site.
  checker.SetRobotState(pose(0.048));
  checker.SetWorkSite(0, target, 0.015);
  report = checker.Check();
  ASSERT_TRUE(report.collision);
  ASSERT_EQ(report.contacts.size(), 1u);
  EXPECT_EQ(report.contacts[0].a, shaft);
  EXPECT_THROW(checker.SetWorkSite(1, target, 0.015), Error);
}

// The contact rule at the port (docs/decisions.md, "contact rules"): an instrument's cannula may
// lean on the ribs that bound its own space, its axis never crossing them. Two 3 mm ribs bound an
// 18 mm gap along x, 8 mm deep in z, the pivot (the RCM) in the gap's middle; the 8 mm shaft runs
// through it, tilted about y. Its surface meets a rib's edge from about 42 degrees, its axis
// enters the bone from about 66. Each verdict is checked on the exact path and on FCL's.
std::shared_ptr<const robot::RobotModel> TiltingShaft() { return ShaftThroughPort("seat", false); }

std::vector<CollisionWorld::FixedMesh> RibsAround(const std::string& name) {
  CollisionWorld::FixedMesh upper{name + "_upper",
                                  BoxMesh({0.009, -0.1, -0.004}, {0.012, 0.1, 0.004}),
                                  Eigen::Isometry3d::Identity(),
                                  false,
                                  true,
                                  false};
  CollisionWorld::FixedMesh lower{name + "_lower",
                                  BoxMesh({-0.012, -0.1, -0.004}, {-0.009, 0.1, 0.004}),
                                  Eigen::Isometry3d::Identity(),
                                  false,
                                  true,
                                  false};
  // One structure, as the import makes "ribs".
  TriangleMesh both = upper.mesh;
  const int offset = static_cast<int>(both.vertices.size());
  both.vertices.insert(both.vertices.end(), lower.mesh.vertices.begin(), lower.mesh.vertices.end());
  for (auto t : lower.mesh.triangles)
    both.triangles.emplace_back(t[0] + offset, t[1] + offset, t[2] + offset);
  return {{name, both, Eigen::Isometry3d::Identity(), false, true, false}};
}

robot::RobotState TiltedShaft(const robot::RobotModel& model, double x, double tilt) {
  robot::RobotState state(model);
  Eigen::VectorXd q(3);
  q << x, tilt, 0.0;
  EXPECT_TRUE(kinematics::ForwardKinematics(model, q, &state).ok());
  return state;
}

// The tilting shaft between the two boxes (named `name`: "ribs" is the chest wall), on the exact
// path or FCL's.
std::shared_ptr<const CollisionWorld> SeatWorld(
    const std::shared_ptr<const robot::RobotModel>& model, bool exact,
    const std::string& name = "ribs") {
  collision::WorldOptions options;
  options.exact_mesh_queries = exact;
  options.acm_samples = 0;
  return CollisionWorld::Build(RibsAround(name), model, options);
}

// The same lean while the instrument works on a target elsewhere (`working`): the shaft is its
// own deepest link, so a wrist (Body::distal), with two exemptions, each what it says: it may
// lean on its port's ribs, axis clear, while its work site is 12 cm away (the motions' start
// pose: the instrument just inside its port, its work site the sample the motion goes to), and
// touch the organ at its work site. A checker that judged such a pair by the work site alone
// called the lean a collision at every start pose whose wrist sits in its rib gap (the
// verification refused a start the plan's own nominal check had passed, issue #41 item 5).
TEST(CollisionWorld, ACannulaMayLeanOnTheRibsOfItsOwnPortButNotPassThroughThem) {
  const auto model = TiltingShaft();
  for (const auto& [exact, working] : std::vector<std::pair<bool, bool>>{
           {true, false}, {false, false}, {true, true}, {false, true}}) {
    SCOPED_TRACE(std::string(exact ? "exact" : "fcl") + (working ? ", working elsewhere" : ""));
    const auto world = SeatWorld(model, exact);
    const int shaft = world->FindBody("shaft"), ribs = world->FindBody("ribs");
    ASSERT_TRUE(world->bodies()[ribs].chest_wall);
    ASSERT_TRUE(world->bodies()[shaft].distal);
    CollisionChecker checker(world);
    if (working) checker.SetWorkSite(0, Eigen::Vector3d(0.0, 0.0, -0.12), 0.015);
    // Upright: clear of the ribs.
    checker.SetRobotState(TiltedShaft(*model, 0.0, 20 * M_PI / 180));
    auto report = checker.Check();
    EXPECT_FALSE(report.collision);
    EXPECT_EQ(report.seat_contacts_allowed, 0);
    // Leaning on the rib's edge at its own port: allowed, and counted.
    checker.SetRobotState(TiltedShaft(*model, 0.0, 50 * M_PI / 180));
    report = checker.Check();
    EXPECT_FALSE(report.collision);
    EXPECT_EQ(report.seat_contacts_allowed, 1);
    EXPECT_FALSE(checker.InCollision());
    // It touches them: its clearance to the ribs is zero, not hidden (a distal link's pairs with
    // the patient are no clearance while it works: zero there by design).
    if (!working) {
      const auto clear = checker.MinimumDistance(Bit(PairClass::kInstrumentPatient));
      ASSERT_TRUE(clear.valid());
      EXPECT_EQ(clear.distance, 0.0);
    }
    // The same lean with the port 5 cm away: these are not its port's ribs.
    checker.SetPortPosition(0, Eigen::Vector3d(0.05, 0, 0));
    report = checker.Check();
    ASSERT_TRUE(report.collision);
    EXPECT_EQ(report.contacts[0].a, shaft);
    EXPECT_EQ(report.contacts[0].b, ribs);
    // Tilted until its axis enters the bone: a collision at its own port too.
    checker.SetRobotState(TiltedShaft(*model, 0.0, 75 * M_PI / 180));
    report = checker.Check();
    ASSERT_TRUE(report.collision);
    EXPECT_EQ(report.contacts[0].b, ribs);
    EXPECT_GE(report.contacts[0].depth, 0.004 - 1e-9);
    EXPECT_TRUE(checker.InCollision());
    // The same boxes as another organ (not the chest wall): the lean is a collision.
    if (working) continue;
    const auto organ = SeatWorld(model, exact, "heart");
    EXPECT_FALSE(organ->bodies()[organ->FindBody("heart")].chest_wall);
    CollisionChecker on_organ(organ);
    on_organ.SetRobotState(TiltedShaft(*model, 0.0, 50 * M_PI / 180));
    EXPECT_TRUE(on_organ.InCollision());
  }
}

// Over seeded random tilts and offsets in the gap: the checker's verdict is a collision exactly
// when the shaft's axis enters a rib (sampled every 0.05 mm along it, a reference independent of
// the hierarchy), and a contact it allows is one the shaft's surface really makes.
TEST(CollisionWorld, TheLeaningRuleHoldsOverRandomTilts) {
  const auto model = TiltingShaft();
  collision::WorldOptions options;
  options.acm_samples = 0;
  const auto world = CollisionWorld::Build(RibsAround("ribs"), model, options);
  CollisionChecker checker(world);
  auto in_rib = [](const Eigen::Vector3d& p) {
    const double ax = std::abs(p.x());
    return ax >= 0.009 && ax <= 0.012 && std::abs(p.y()) <= 0.1 && std::abs(p.z()) <= 0.004;
  };
  auto to_rib = [](const Eigen::Vector3d& p) {  // distance from p to the nearer box
    const double ax = std::abs(p.x());
    const Eigen::Vector3d d(std::max({0.009 - ax, ax - 0.012, 0.0}),
                            std::max(std::abs(p.y()) - 0.1, 0.0),
                            std::max(std::abs(p.z()) - 0.004, 0.0));
    return d.norm();
  };
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> tilt(-80 * M_PI / 180, 80 * M_PI / 180),
      offset(-0.001, 0.001);
  int leaning = 0, through = 0, clear = 0;
  for (int i = 0; i < 400; ++i) {
    const double x = offset(rng), t = tilt(rng);
    const robot::RobotState state = TiltedShaft(*model, x, t);
    const Eigen::Isometry3d X_WS = state.X_WL[model->GetLink("shaft")];
    const Eigen::Vector3d a = X_WS * Eigen::Vector3d(0, 0, 0.05),
                          b = X_WS * Eigen::Vector3d(0, 0, -0.15);
    bool axis_in = false;
    double nearest = 1.0, deepest = 0.0;
    for (int k = 0; k <= 4000; ++k) {
      const Eigen::Vector3d p = a + (b - a) * (k / 4000.0);
      nearest = std::min(nearest, to_rib(p));
      if (in_rib(p)) {
        axis_in = true;
        const double ax = std::abs(p.x());
        deepest = std::max(deepest, std::min({ax - 0.009, 0.012 - ax, 0.004 - std::abs(p.z())}));
      }
    }
    // Cases within 0.2 mm of a rule's boundary are left out (the sampling's own error).
    if ((axis_in && deepest < 2e-4) || (!axis_in && nearest < 2e-4) ||
        std::abs(nearest - 0.004) < 2e-4)
      continue;
    checker.SetRobotState(state);
    const auto report = checker.Check();
    EXPECT_EQ(report.collision, axis_in) << "tilt " << t * 180 / M_PI << " deg, offset " << x;
    if (!axis_in) EXPECT_EQ(report.seat_contacts_allowed, nearest < 0.004 ? 1 : 0) << t;
    (axis_in ? through : nearest < 0.004 ? leaning : clear)++;
  }
  // The cases cover all three outcomes.
  EXPECT_GT(leaning, 40);
  EXPECT_GT(through, 40);
  EXPECT_GT(clear, 40);
}

TEST(CollisionWorld, DegenerateMeshesAreRejectedByName) {
  auto message = [](TriangleMesh mesh) {
    try {
      CollisionWorld::Build(
          {{"heart", std::move(mesh), Eigen::Isometry3d::Identity(), false, true}}, nullptr);
    } catch (const Error& e) {
      return std::string(e.what());
    }
    return std::string("(accepted)");
  };
  EXPECT_NE(message(TriangleMesh{}).find("patient structure 'heart': mesh is empty"),
            std::string::npos);
  TriangleMesh nan = BoxMesh(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones());
  nan.vertices[3].y() = std::nan("");
  EXPECT_NE(message(nan).find("'heart': vertex 3 is not finite"), std::string::npos)
      << message(nan);
  TriangleMesh flat = BoxMesh(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones());
  flat.triangles[5] = Eigen::Vector3i(1, 1, 2);
  EXPECT_NE(message(flat).find("'heart': triangle 5 has zero area"), std::string::npos)
      << message(flat);
  TriangleMesh bad_index = BoxMesh(Eigen::Vector3d::Zero(), Eigen::Vector3d::Ones());
  bad_index.triangles[0] = Eigen::Vector3i(0, 1, 99);
  EXPECT_NE(message(bad_index).find("'heart': triangle 0 indexes a vertex"), std::string::npos);
  // Robot shapes with no size are refused when the robot is loaded, naming file, line and field.
  try {
    Probes("{shape: sphere, radius: 0}", "{shape: sphere, radius: 0.01}");
    ADD_FAILURE();
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("collision[0].radius: 0 must be positive"),
              std::string::npos)
        << e.what();
  }
}

// The da Vinci cart over a synthetic patient (an ellipsoid body with a heart), on the table.
struct CartScene {
  std::shared_ptr<const robot::RobotModel> cart;
  patient::PatientModel patient;
  std::shared_ptr<const CollisionWorld> world;
};

CartScene MakeCartScene() {
  CartScene s;
  s.cart = std::make_shared<const robot::RobotModel>(
      robot::LoadRobot(test::SourcePath("robots/davinci-classic/cart.yaml")));
  s.patient.name = "ellipsoid";
  s.patient.structures.push_back({"skin", Ellipsoid({0, 0, 0}, {0.17, 0.12, 0.3}, 60, 120), 0, 0});
  s.patient.structures.push_back(
      {"heart", Ellipsoid({0.03, -0.02, 0.02}, {0.06, 0.05, 0.07}, 30, 60), 0, 0});
  // Patient frame P: LPS; supine on the table, head toward +x_W.
  s.patient.X_WP = Eigen::Isometry3d::Identity();
  s.patient.X_WP.linear() << 0, 0, 1, 1, 0, 0, 0, -1,
      0;  // columns: x_P → y_W, y_P → −z_W, z_P → x_W
  s.patient.X_WP.translation() = Eigen::Vector3d(0, 0, s.patient.table.height + 0.12);
  s.world = CollisionWorld::Build(&s.patient, s.cart);
  return s;
}

robot::RobotState RandomCartState(const robot::RobotModel& cart, std::mt19937& rng) {
  robot::RobotState state(cart);
  state.X_WB.translation() = Eigen::Vector3d(-1.45, 0, 0);  // past the table's foot, facing it
  // Setup-joint columns raised so that the arms pass above the patient.
  for (const char* column : {"psm1_suj_column", "psm2_suj_column", "ecm_suj_column"}) {
    kinematics::SetHeldJoint(cart, column, 0.45, &state);
  }
  for (;;) {
    Eigen::VectorXd q(cart.num_positions());
    for (int i = 0; i < q.size(); ++i) {
      const auto& lim = cart.joint(cart.active_joints()[i]).limits;
      q[i] = std::uniform_real_distribution<double>(lim.lower, lim.upper)(rng);
    }
    if (kinematics::ForwardKinematics(cart, q, &state).ok()) return state;
  }
}

TEST(CollisionWorld, CartSelfPairsOfTheParallelogramsAreAllowedAndArmsStillCollide) {
  const CartScene s = MakeCartScene();
  const auto& w = *s.world;
  EXPECT_EQ(w.arms().size(), 3u);
  EXPECT_EQ(w.ports().size(), 3u);  // psm1, psm2, ecm
  EXPECT_GT(w.auto_allowed_pairs(), 0);
  // Links joined by a joint never collide.
  const int bottom = w.FindBody("psm1_pitch_bottom_link"),
            back = w.FindBody("psm1_pitch_back_link");
  ASSERT_GE(bottom, 0);
  EXPECT_TRUE(w.Allowed(bottom, back));
  // Links of different arms always count.
  EXPECT_FALSE(w.Allowed(w.FindBody("psm1_yaw_link"), w.FindBody("psm2_yaw_link")));
  EXPECT_EQ(w.Classify(w.FindBody("psm1_yaw_link"), w.FindBody("psm2_yaw_link")),
            PairClass::kArmArm);
  EXPECT_EQ(w.Classify(w.FindBody("psm1_insertion_link#1"), w.FindBody("skin")),
            PairClass::kInstrumentPatient);
  CollisionChecker checker(s.world);
  std::mt19937 rng(5);
  int arm_arm = 0, self = 0;
  for (int i = 0; i < 300; ++i) {
    checker.SetRobotState(RandomCartState(*s.cart, rng));
    for (const auto& c : checker.Check().contacts) {
      arm_arm += c.cls == PairClass::kArmArm;
      self += c.cls == PairClass::kSelf;
      EXPECT_FALSE(w.Allowed(c.a, c.b));
    }
  }
  EXPECT_GT(arm_arm, 0);  // random arms do run into each other
  EXPECT_EQ(self,
            0);  // within an arm, only the setup joints could meet the arm: not at these settings
}

// Bodies in a surgeon's words, by what they are in the world (an instrument link through its
// port, a wrist, another arm link, a patient structure), not by their names: a shaft called an
// arm, or a pair with the patient's structure first, fails.
TEST(CollisionWorld, ABodyIsDescribedByWhatItIs) {
  const CartScene s = MakeCartScene();
  const auto& w = *s.world;
  const int shaft = w.FindBody("psm1_insertion_link#1"), skin = w.FindBody("skin"),
            arm = w.FindBody("psm2_pitch_bottom_link"), table = w.FindBody("table");
  ASSERT_GE(shaft, 0);
  ASSERT_GE(skin, 0);
  ASSERT_GE(arm, 0);
  ASSERT_GE(table, 0);
  ASSERT_GE(w.bodies()[shaft].port, 0);
  ASSERT_FALSE(w.bodies()[shaft].distal);
  EXPECT_EQ(w.DescribeBody(shaft), "psm1's shaft (psm1_insertion_link#1)");
  EXPECT_EQ(w.DescribeBody(arm), "psm2's arm (psm2_pitch_bottom_link)");
  EXPECT_EQ(w.DescribeBody(skin), "the skin");
  EXPECT_EQ(w.DescribePair(skin, shaft), "psm1's shaft (psm1_insertion_link#1) against the skin");
  EXPECT_EQ(w.DescribePair(arm, table), "psm2's arm (psm2_pitch_bottom_link) against the table");
  int wrists = 0;
  for (int b = 0; b < static_cast<int>(w.bodies().size()); ++b) {
    if (!w.bodies()[b].distal) continue;
    ++wrists;
    EXPECT_EQ(w.DescribeBody(b), w.arms()[w.bodies()[b].arm].name + "'s wrist (" + w.bodies()[b].name + ")");
  }
  EXPECT_GT(wrists, 0);
}

// Checking one arm (what a planner that moved that arm alone needs) finds exactly the contacts of
// the whole check that involve a body of that arm, for every pair class, over random poses of the
// cart's arms through the patient: a filter that dropped the arm's pairs with the patient or with
// another arm, or kept another arm's, fails.
TEST(CollisionWorld, CheckingOneArmFindsExactlyThatArmsContacts) {
  const CartScene s = MakeCartScene();
  const auto& w = *s.world;
  CollisionChecker checker(s.world);
  std::mt19937 rng(17);
  std::vector<int> with_patient(w.arms().size(), 0), with_arm(w.arms().size(), 0);
  for (int i = 0; i < 200; ++i) {
    // Columns lowered and the cart moved in at random so that the arms also reach the patient.
    robot::RobotState state = RandomCartState(*s.cart, rng);
    for (const char* column : {"psm1_suj_column", "psm2_suj_column", "ecm_suj_column"}) {
      kinematics::SetHeldJoint(*s.cart, column,
                               std::uniform_real_distribution<double>(0.0, 0.45)(rng), &state);
    }
    state.X_WB.translation().x() = std::uniform_real_distribution<double>(-1.3, -0.4)(rng);
    ASSERT_TRUE(kinematics::ForwardKinematics(*s.cart, state.q, &state).ok());
    checker.SetRobotState(state);
    const auto all = checker.Check().contacts;
    for (int arm = 0; arm < static_cast<int>(w.arms().size()); ++arm) {
      std::vector<std::pair<int, int>> want, got;
      for (const auto& c : all) {
        if (w.bodies()[c.a].arm == arm || w.bodies()[c.b].arm == arm) want.emplace_back(c.a, c.b);
      }
      for (const auto& c : checker.Check(collision::kAllMovingPairs, arm).contacts) {
        got.emplace_back(c.a, c.b);
        const bool robot_a = w.bodies()[c.a].kind == collision::Body::Kind::kRobot;
        const bool robot_b = w.bodies()[c.b].kind == collision::Body::Kind::kRobot;
        with_patient[arm] += robot_a != robot_b;
        with_arm[arm] += c.cls == PairClass::kArmArm;
      }
      EXPECT_EQ(got, want) << "pose " << i << ", arm " << w.arms()[arm].name;
      EXPECT_EQ(checker.InCollision(collision::kAllMovingPairs, arm), !want.empty())
          << "pose " << i << ", arm " << w.arms()[arm].name;
    }
  }
  for (std::size_t arm = 0; arm < w.arms().size(); ++arm) {
    EXPECT_GT(with_patient[arm], 0) << w.arms()[arm].name;
    EXPECT_GT(with_arm[arm], 0) << w.arms()[arm].name;
  }
}

// The same seeded queries from two threads (each with its own checker over one world) give
// exactly the answers of one thread.
TEST(CollisionWorld, ANonFinitePoseIsRefusedNamingTheLink) {
  const CartScene s = MakeCartScene();
  CollisionChecker checker(s.world);
  std::mt19937 rng(9);
  robot::RobotState state = RandomCartState(*s.cart, rng);
  checker.SetRobotState(state);
  const bool before = checker.InCollision();
  const int link = s.cart->FindLink("psm1_yaw_link");
  ASSERT_GE(link, 0);
  state.X_WL[link].translation().x() = std::numeric_limits<double>::quiet_NaN();
  try {
    checker.SetRobotState(state);
    FAIL() << "a NaN link pose was accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("psm1_yaw_link"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("non-finite"), std::string::npos) << e.what();
  }
  // The checker still answers for the last good state.
  EXPECT_EQ(checker.InCollision(), before);
}

// Our exact capsule/sphere/box–mesh queries (the default) against FCL's for every pair, on the
// whole cart over an ellipsoid patient: same collisions, same minimum distances. (FCL's
// collision test with libccd missed shallow capsule–skin contacts its own distance query saw;
// the checker asks FCL with its own GJK solver, and then the two agree.)
TEST(CollisionWorld, ExactMeshQueriesAgreeWithFcl) {
  const CartScene s = MakeCartScene();
  collision::WorldOptions fcl_only;
  fcl_only.exact_mesh_queries = false;
  const auto peer = CollisionWorld::Build(&s.patient, s.cart, fcl_only);
  CollisionChecker ours(s.world), theirs(peer);
  const unsigned robot_patient = Bit(PairClass::kArmPatient) | Bit(PairClass::kInstrumentPatient);
  int compared = 0, colliding = 0, arm_contacts = 0, bounded = 0;
  for (int i = 0; i < 60; ++i) {
    std::mt19937 rng(5000 + i);
    robot::RobotState state = RandomCartState(*s.cart, rng);
    if (i %
        2) {  // cart nearer, setup columns anywhere in their range: arms down into the patient too
      state.X_WB.translation().x() = std::uniform_real_distribution<double>(-1.3, -0.8)(rng);
      for (const char* column : {"psm1_suj_column", "psm2_suj_column", "ecm_suj_column"}) {
        const auto& lim = s.cart->joint(s.cart->FindJoint(column)).limits;
        kinematics::SetHeldJoint(*s.cart, column,
                                 std::uniform_real_distribution<double>(lim.lower, lim.upper)(rng),
                                 &state);
      }
      ASSERT_TRUE(kinematics::ForwardKinematics(*s.cart, state.q, &state).ok());
    }
    ours.SetRobotState(state);
    theirs.SetRobotState(state);
    const auto a = ours.Check(robot_patient), b = theirs.Check(robot_patient);
    std::vector<std::pair<int, int>> pa, pb;
    for (const auto& c : a.contacts) pa.emplace_back(c.a, c.b);
    for (const auto& c : b.contacts) pb.emplace_back(c.a, c.b);
    EXPECT_EQ(pa, pb) << "state " << i;
    EXPECT_EQ(a.port_contacts_allowed, b.port_contacts_allowed) << "state " << i;
    EXPECT_EQ(ours.InCollision(robot_patient), theirs.InCollision(robot_patient)) << "state " << i;
    // Every class: the arms against each other (capsule–capsule and capsule–box in closed form).
    std::vector<std::pair<int, int>> all_a, all_b;
    for (const auto& c : ours.Check().contacts) all_a.emplace_back(c.a, c.b);
    for (const auto& c : theirs.Check().contacts) all_b.emplace_back(c.a, c.b);
    EXPECT_EQ(all_a, all_b) << "state " << i;
    arm_contacts += static_cast<int>(all_a.size() - pa.size());
    colliding += a.collision;
    const auto da = ours.MinimumDistance(robot_patient), db = theirs.MinimumDistance(robot_patient);
    EXPECT_NEAR(da.distance, db.distance, 1e-6) << "state " << i;
    if (da.distance > 1e-4) {
      ++compared;
      EXPECT_EQ(std::make_pair(da.a, da.b), std::make_pair(db.a, db.b)) << "state " << i;
      EXPECT_NEAR((da.p_W_a - da.p_W_b).norm(), da.distance, 1e-9);
      EXPECT_NEAR((da.p_W_a - db.p_W_a).norm(), 0.0, 1e-4)
          << "state " << i << " " << s.world->bodies()[da.a].name << " - "
          << s.world->bodies()[da.b].name << " " << da.p_W_a.transpose() << " / "
          << da.p_W_b.transpose() << " fcl " << db.p_W_a.transpose() << " / "
          << db.p_W_b.transpose() << " d " << da.distance;
    }
    // Whole-cart distance too (arm-arm first, then the patient and the table).
    const collision::Clearance whole = ours.MinimumDistance();
    EXPECT_NEAR(whole.distance, theirs.MinimumDistance().distance, 1e-6) << "state " << i;
    // Asked only for a distance below a bound (a path's minimum so far): the same pair and
    // distance when the minimum lies below it, nothing (invalid) when it does not.
    if (whole.valid() && whole.distance > 0.0) {
      ++bounded;
      const collision::Clearance above =
          ours.MinimumDistance(collision::kAllMovingPairs, -1, 1.5 * whole.distance + 1e-6);
      ASSERT_TRUE(above.valid()) << "state " << i;
      EXPECT_EQ(above.distance, whole.distance) << "state " << i;
      EXPECT_EQ(std::make_pair(above.a, above.b), std::make_pair(whole.a, whole.b)) << "state " << i;
      EXPECT_FALSE(ours.MinimumDistance(collision::kAllMovingPairs, -1, whole.distance).valid())
          << "state " << i;
      EXPECT_FALSE(ours.MinimumDistance(collision::kAllMovingPairs, -1, 0.5 * whole.distance).valid())
          << "state " << i;
    }
  }
  EXPECT_GT(bounded, 10);
  EXPECT_GT(compared, 10);
  EXPECT_GT(colliding, 5);
  EXPECT_GT(arm_contacts, 20);
}

TEST(CollisionWorld, TwoThreadsAnswerExactlyAsOne) {
  const CartScene s = MakeCartScene();
  constexpr int kQueries = test::Trials(10000, 2500);  // TSan runs a quarter
  struct Answer {
    bool in_collision;
    std::vector<std::pair<int, int>> pairs;
    double distance;
    int a, b;
    bool operator==(const Answer& o) const {
      return in_collision == o.in_collision && pairs == o.pairs && distance == o.distance &&
             a == o.a && b == o.b;
    }
  };
  auto run = [&](int begin, int end, std::vector<Answer>* out) {
    CollisionChecker checker(s.world);
    for (int i = begin; i < end; ++i) {
      std::mt19937 rng(1000 + i);
      checker.SetRobotState(RandomCartState(*s.cart, rng));
      Answer a;
      a.in_collision = checker.InCollision();
      for (const auto& c : checker.Check().contacts) a.pairs.emplace_back(c.a, c.b);
      const auto d =
          checker.MinimumDistance(Bit(PairClass::kArmPatient) | Bit(PairClass::kInstrumentPatient));
      a.distance = d.distance;
      a.a = d.a;
      a.b = d.b;
      (*out)[i] = a;
    }
  };
  std::vector<Answer> one(kQueries), two(kQueries);
  run(0, kQueries, &one);
  std::thread t1(run, 0, kQueries / 2, &two), t2(run, kQueries / 2, kQueries, &two);
  t1.join();
  t2.join();
  int collisions = 0, differences = 0;
  for (int i = 0; i < kQueries; ++i) {
    collisions += one[i].in_collision;
    differences += !(one[i] == two[i]);
    EXPECT_EQ(one[i].in_collision, !one[i].pairs.empty());
  }
  EXPECT_EQ(differences, 0);
  EXPECT_GT(collisions, kQueries / 50);
  EXPECT_LT(collisions, kQueries - kQueries / 50);
}

// A world with the heart moved in place (its hierarchy shared, the robustness check's world)
// answers as a world built anew from the moved heart's vertices: the same contacts, distances
// within rounding, the same sight lines; the original world is left as it was. A moved world
// that ignored the move, moved the skin too, or moved by the wrong frame's vector fails.
TEST(CollisionWorld, AWorldWithABodyMovedInPlaceAnswersAsOneBuiltMoved) {
  const CartScene s = MakeCartScene();
  const auto probes = Probes("{shape: capsule, radius: 0.01, length: 0.06}",
                             "{shape: sphere, radius: 0.015}");
  const Eigen::Vector3d heart_W = s.patient.X_WP * Eigen::Vector3d(0.03, -0.02, 0.02);
  const auto original_world = CollisionWorld::Build(&s.patient, probes);
  for (const Eigen::Vector3d d_P : {Eigen::Vector3d(0.02, 0, 0), Eigen::Vector3d(0, -0.03, 0.01),
                                    Eigen::Vector3d(-0.01, 0.015, -0.02)}) {
    patient::PatientModel moved = s.patient;
    for (auto& v : moved.structures[1].mesh.vertices) v += d_P;
    const auto rebuilt = CollisionWorld::Build(&moved, probes);
    const auto in_place =
        original_world->WithBodiesMoved({"heart"}, s.patient.X_WP.linear() * d_P);
    CollisionChecker a(rebuilt), b(in_place), original(original_world),
        fresh(CollisionWorld::Build(&s.patient, probes));
    const int heart = rebuilt->FindBody("heart");
    int differing_from_unmoved = 0, heart_contacts = 0;
    for (int i = 0; i < 400; ++i) {
      std::mt19937 rng(77 + i);
      std::uniform_real_distribution<double> u(-0.09, 0.09);
      const robot::RobotState state =
          PlaceProbes(*probes, heart_W + Eigen::Vector3d(u(rng), u(rng), u(rng)),
                      heart_W + Eigen::Vector3d(u(rng), u(rng), u(rng)));
      for (CollisionChecker* c : {&a, &b, &original, &fresh}) c->SetRobotState(state);
      std::vector<std::pair<int, int>> pa, pb, po, pf;
      for (const auto& c : a.Check().contacts) pa.emplace_back(c.a, c.b);
      for (const auto& c : b.Check().contacts) pb.emplace_back(c.a, c.b);
      for (const auto& c : original.Check().contacts) po.emplace_back(c.a, c.b);
      for (const auto& c : fresh.Check().contacts) pf.emplace_back(c.a, c.b);
      EXPECT_EQ(pa, pb) << "state " << i;
      EXPECT_EQ(po, pf) << "state " << i << ": the original world changed";
      differing_from_unmoved += pa != po;
      for (const auto& p : pa) heart_contacts += p.first == heart || p.second == heart;
    }
    EXPECT_GT(differing_from_unmoved, 10) << "the move changed few answers: the test sees little";
    EXPECT_GT(heart_contacts, 20);
    // Sight lines through the heart's old and new places.
    for (int i = 0; i < 200; ++i) {
      std::mt19937 rng(500 + i);
      std::uniform_real_distribution<double> u(-0.08, 0.08);
      const Eigen::Vector3d to = heart_W + Eigen::Vector3d(u(rng), u(rng), u(rng));
      const Eigen::Vector3d from = to + Eigen::Vector3d(0.0, 0.0, 0.3);
      EXPECT_EQ(rebuilt->FirstAcross(from, to, 0.001).body,
                in_place->FirstAcross(from, to, 0.001).body);
    }
  }
  EXPECT_THROW(original_world->WithBodiesMoved({"liver"}, Eigen::Vector3d::Zero()), Error);
}

// The endoscope's line of sight (issue #41, item 5): a line is hidden exactly when its part
// outside the margin at its far end crosses a patient structure; a structure that is not the
// patient's (the table) never hides anything; the body named is the one met first.
TEST(CollisionWorld, ALineOfSightIsHiddenExactlyWhenItCrossesAPatientStructure) {
  Eigen::Isometry3d X_WH = Eigen::Isometry3d::Identity();  // the "heart", turned and moved
  X_WH.linear() = Eigen::AngleAxisd(0.4, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  X_WH.translation() = Eigen::Vector3d(0.02, -0.01, 0.03);
  const Eigen::Vector3d lo(-0.05, -0.04, -0.03), hi(0.05, 0.04, 0.03);
  Eigen::Isometry3d X_WT = Eigen::Isometry3d::Identity();
  X_WT.translation() = Eigen::Vector3d(0, 0, -0.2);
  const auto world = CollisionWorld::Build(
      {{"heart", BoxMesh(lo, hi), X_WH, false, true},
       {"table", BoxMesh({-0.3, -0.3, -0.02}, {0.3, 0.3, 0.02}), X_WT, false, false}},
      nullptr);
  const int heart = world->FindBody("heart");
  // Whether the segment [a, b] meets the box (slab test in the box's frame).
  auto crosses = [&](const Eigen::Vector3d& a_W, const Eigen::Vector3d& b_W) {
    const Eigen::Vector3d a = X_WH.inverse() * a_W, d = X_WH.inverse() * b_W - a;
    double t0 = 0, t1 = 1;
    for (int k = 0; k < 3; ++k) {
      if (std::abs(d[k]) < 1e-15) {
        if (a[k] < lo[k] || a[k] > hi[k]) return false;
        continue;
      }
      double ta = (lo[k] - a[k]) / d[k], tb = (hi[k] - a[k]) / d[k];
      if (ta > tb) std::swap(ta, tb);
      t0 = std::max(t0, ta);
      t1 = std::min(t1, tb);
    }
    return t0 <= t1;
  };
  std::mt19937 rng(41);
  std::uniform_real_distribution<double> u(-0.15, 0.15);
  int hidden = 0, clear = 0;
  for (int i = 0; i < 2000; ++i) {
    const Eigen::Vector3d from(u(rng), u(rng), u(rng)), to(u(rng), u(rng), u(rng));
    // A camera inside an organ is a collision, not a question of sight: the query is about
    // surfaces met, and a line wholly inside a closed surface meets none.
    if (crosses(from, from)) continue;
    const double margin = i % 2 ? 0.0 : 0.01;
    const double length = (to - from).norm();
    if (length <= margin) continue;
    const Eigen::Vector3d end = to - margin * (to - from) / length;
    // Leave out lines that only graze the box (within 0.1 mm): the mesh's and the slab test's
    // rounding may differ there.
    bool grazing = false;
    for (double e : {-1e-4, 1e-4}) {
      const Eigen::Vector3d n = (end - from).cross(Eigen::Vector3d(0.3, -0.5, 0.8)).normalized();
      grazing = grazing || crosses(from + e * n, end + e * n) != crosses(from, end);
    }
    if (grazing) continue;
    const collision::SightLine sight = world->FirstAcross(from, to, margin);
    const bool expected = crosses(from, end);
    ASSERT_EQ(!sight.clear(), expected) << "case " << i;
    if (expected) {
      EXPECT_EQ(sight.body, heart);
      // The point reported lies on the line and on the box's surface (within rounding).
      const Eigen::Vector3d p_H = X_WH.inverse() * sight.p_W;
      EXPECT_LT(((p_H - lo).cwiseMin(hi - p_H)).minCoeff(), 1e-9);
      EXPECT_LT((sight.p_W - from).cross(end - from).norm() / (end - from).norm(), 1e-9);
      ++hidden;
    } else {
      ++clear;
    }
  }
  EXPECT_GT(hidden, 100);
  EXPECT_GT(clear, 100);
  // Through the table alone: clear (not the patient); through the table and the heart: the heart.
  EXPECT_TRUE(world->FirstAcross({0.25, 0.25, -0.3}, {0.25, 0.25, -0.1}, 0.0).clear());
  EXPECT_EQ(world->FirstAcross({0.02, -0.01, -0.3}, {0.02, -0.01, 0.2}, 0.0).body, heart);
  // A point on the surface, seen from outside: clear once the margin takes in the surface.
  const Eigen::Vector3d on_W = X_WH * Eigen::Vector3d(0.0, 0.0, hi.z());
  const Eigen::Vector3d out_W = X_WH * Eigen::Vector3d(0.0, 0.0, hi.z() + 0.1);
  EXPECT_TRUE(world->FirstAcross(out_W, on_W, 0.001).clear());
  EXPECT_FALSE(world->FirstAcross(out_W, X_WH * Eigen::Vector3d(0, 0, 0), 0.001).clear());
}

}  // namespace
}  // namespace trocar
