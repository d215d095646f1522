// Hot paths allocate nothing (issue #18): a control step of every controller on every kind of
// robot (serial, closures, software RCM), forward kinematics with closures (including a step a
// closure refuses), and Jacobians. This executable counts every heap allocation: operator new
// is replaced here, and malloc, calloc, realloc and the aligned allocators (Eigen's path) are
// wrapped by the linker (--wrap) in everything linked statically, which is trocar's core and the
// Eigen code inlined into it. A counter over a window of calls must stay at zero.
#include <gtest/gtest.h>

#include <atomic>
#include <cstdlib>
#include <new>
#include <random>

#include "control/control_loop.hpp"
#include "control/controller.hpp"
#include "kinematics/forward_kinematics.hpp"
#include "kinematics/jacobian.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace {
std::atomic<long> g_allocations{0};
volatile double g_sink = 0.0;
// Keeps a result alive so the optimiser cannot drop the work that made it.
void benchmark_sink(double x) { g_sink = g_sink + x; }
}  // namespace

extern "C" {
void* __real_malloc(std::size_t size);
void* __real_calloc(std::size_t n, std::size_t size);
void* __real_realloc(void* p, std::size_t size);
int __real_posix_memalign(void** p, std::size_t alignment, std::size_t size);
void* __real_aligned_alloc(std::size_t alignment, std::size_t size);
void* __wrap_malloc(std::size_t size) {
  ++g_allocations;
  return __real_malloc(size);
}
void* __wrap_calloc(std::size_t n, std::size_t size) {
  ++g_allocations;
  return __real_calloc(n, size);
}
void* __wrap_realloc(void* p, std::size_t size) {
  ++g_allocations;
  return __real_realloc(p, size);
}
int __wrap_posix_memalign(void** p, std::size_t alignment, std::size_t size) {
  ++g_allocations;
  return __real_posix_memalign(p, alignment, size);
}
void* __wrap_aligned_alloc(std::size_t alignment, std::size_t size) {
  ++g_allocations;
  return __real_aligned_alloc(alignment, size);
}
}

void* operator new(std::size_t size) {
  ++g_allocations;
  if (void* p = __real_malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void* operator new[](std::size_t size) { return operator new(size); }
void operator delete(void* p) noexcept { std::free(p); }
void operator delete[](void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
void operator delete[](void* p, std::size_t) noexcept { std::free(p); }

namespace trocar {
namespace {

using control::Vector6d;
using robot::RobotModel;
using robot::RobotState;

// Allocations made by f().
template <typename F>
long AllocationsIn(F&& f) {
  const long before = g_allocations.load();
  f();
  return g_allocations.load() - before;
}

TEST(HotPathAllocations, TheCounterSeesEigenAndStandardAllocations) {
  // The test is only worth something if it would notice: a dynamic Eigen vector (malloc through
  // Eigen's aligned allocator) and a std::vector (operator new) are both counted.
  EXPECT_GE(AllocationsIn([] {
              Eigen::VectorXd v = Eigen::VectorXd::Random(50);
              benchmark_sink(v.sum());
            }),
            1);
  EXPECT_GE(AllocationsIn([] {
              std::vector<int> v(100, 1);
              benchmark_sink(static_cast<double>(v[7]));
            }),
            1);
}

const RobotModel& Robot(const char* file) {
  static std::map<std::string, RobotModel> cache;
  auto it = cache.find(file);
  if (it == cache.end()) it = cache.emplace(file, robot::LoadRobot(test::SourcePath(file))).first;
  return it->second;
}

const char* kRobots[] = {"robots/pa10/pa10.yaml", "robots/pa10/pa10.urdf",
                         "robots/davinci-classic/psm.yaml", "robots/davinci-classic/ecm.yaml",
                         "robots/prismatic-test/prismatic10.yaml"};

TEST(HotPathAllocations, ForwardKinematicsWithClosuresAndJacobians) {
  for (const char* file : kRobots) {
    const RobotModel& model = Robot(file);
    RobotState state(model);
    std::mt19937 rng(11);
    std::vector<Eigen::VectorXd> qs;
    for (int k = 0; k < 200; ++k) qs.push_back(test::RandomConfiguration(model, &rng));
    kinematics::Matrix6Xd J(6, model.num_positions());
    kinematics::Matrix6Xd J_point(6, model.num_positions());
    int refused = 0;
    const long n = AllocationsIn([&] {
      for (const auto& q : qs) {
        const auto result = kinematics::ForwardKinematics(model, q, &state);
        refused += result.ok() ? 0 : 1;
        kinematics::ComputeFrameJacobian(model, state, model.tool_frame(), &J);
        kinematics::ComputeJacobian(model, state, model.num_links() - 1, Eigen::Vector3d(0.01, 0, 0), &J_point);
      }
    });
    EXPECT_EQ(n, 0) << file;
    benchmark_sink(J.sum() + J_point.sum() + refused);
  }
}

TEST(HotPathAllocations, AClosureThatRefusesUndoesWithoutCopyingTheState) {
  const RobotModel& model = Robot("robots/davinci-classic/psm.yaml");
  ASSERT_FALSE(model.closures().empty());
  RobotState state(model);
  ASSERT_TRUE(kinematics::ForwardKinematics(model, model.defaults().HomeOr(model.neutral_configuration()), &state).ok());
  // Drive each joint far past its range until a closure refuses (the parallelogram cannot
  // assemble), then check the undo: the state as it was, and no copy of it made (a copy is one
  // allocation per buffer: q, joint values, their gradient, link poses, closure drivers: five).
  // The refusal's message is formatted text (an ostringstream, its string and the result's
  // copy: four allocations here): a refusal is a rare event, and the message says why.
  bool refused = false;
  for (int i = 0; i < model.num_positions() && !refused; ++i) {
    for (double value : {-40.0, 40.0, 3.0, -3.0}) {
      Eigen::VectorXd q = model.defaults().HomeOr(model.neutral_configuration());
      q[i] = value;
      const Eigen::VectorXd joint_values = state.joint_values;
      const Eigen::VectorXd q_before = state.q;
      kinematics::ConfigurationResult result;
      const long n = AllocationsIn([&] { result = kinematics::SetConfiguration(model, q, &state); });
      if (result.ok()) {
        EXPECT_EQ(n, 0);
        ASSERT_TRUE(kinematics::ForwardKinematics(model, model.defaults().HomeOr(model.neutral_configuration()), &state).ok());
        continue;
      }
      refused = true;
      EXPECT_LE(n, 4) << result.message;
      EXPECT_EQ(state.joint_values, joint_values);
      EXPECT_EQ(state.q, q_before);
      break;
    }
  }
  EXPECT_TRUE(refused) << "no configuration made a closure refuse: the undo was not exercised";
}

Vector6d Gains() { return (Vector6d() << 20, 20, 20, 40, 40, 40).finished(); }

void ExpectControlStepsAllocateNothing(const RobotModel& model, std::unique_ptr<control::Controller> controller,
                                       const std::string& what, bool position_only) {
  control::ControlLoop loop(model, std::move(controller), model.defaults().HomeOr(model.neutral_configuration()));
  control::TaskTarget target;
  target.X_WD = loop.ToolPose();
  target.position_only = position_only;
  const Eigen::Vector3d start = target.X_WD.translation();
  loop.Step(target, 1e-3);  // the first step may size buffers
  long k = 0;
  const long n = AllocationsIn([&] {
    for (; k < 500; ++k) {  // a small circle, so every step has work to do
      const double phase = 2e-2 * static_cast<double>(k);
      target.X_WD.translation() = start + 5e-3 * Eigen::Vector3d(std::cos(phase) - 1.0, std::sin(phase), 0);
      benchmark_sink(loop.Step(target, 1e-3).position_error);
    }
  });
  EXPECT_EQ(n, 0) << what << (position_only ? " (position only)" : "");
}

TEST(HotPathAllocations, AControlStepOfEveryControllerOnEveryRobot) {
  for (const char* file : kRobots) {
    const RobotModel& model = Robot(file);
    for (const char* name : {"jt", "dls", "jla"}) {
      for (bool position_only : {false, true}) {
        ExpectControlStepsAllocateNothing(model, control::MakeControllerWithGains(name, Gains()),
                                          std::string(file) + " " + name, position_only);
      }
    }
  }
  const RobotModel& model = Robot("robots/pa10/pa10_instrument.yaml");
  RobotState state(model);
  ASSERT_TRUE(kinematics::ForwardKinematics(model, model.defaults().HomeOr(model.neutral_configuration()), &state).ok());
  const int rod = model.GetLink("rod");
  const Eigen::Vector3d p_WR = state.X_WL[rod] * Eigen::Vector3d(0, 0, -0.1);
  for (bool position_only : {false, true}) {
    ExpectControlStepsAllocateNothing(
        model, std::make_unique<control::SoftwareRcmController>(Gains(), rod, Eigen::Vector3d(0, 0, -0.35), p_WR),
        "pa10_instrument rcm", position_only);
  }
}

}  // namespace
}  // namespace trocar
