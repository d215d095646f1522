#include "control/runner.hpp"

#include <array>
#include <chrono>
#include <thread>

#include <gtest/gtest.h>

#include "common/error.hpp"

namespace trocar {
namespace {

TEST(TripleBuffer, ReaderAlwaysSeesAConsistentLatestSnapshot) {
  // The writer publishes snapshots whose fields all derive from one counter; a torn read would
  // mix counters. The reader must also never see the counter go back.
  using Snapshot = std::array<long, 16>;
  control::TripleBuffer<Snapshot> buffer(Snapshot{});
  constexpr long kWrites = 200000;
  std::thread writer([&] {
    for (long i = 1; i <= kWrites; ++i) {
      Snapshot s;
      for (long k = 0; k < 16; ++k) s[k] = i * (k + 1);
      buffer.Publish(s);
    }
  });
  long last = 0, fresh_reads = 0;
  Snapshot s;
  while (last < kWrites) {
    if (buffer.Read(&s)) ++fresh_reads;
    for (long k = 0; k < 16; ++k) ASSERT_EQ(s[k], s[0] * (k + 1)) << "torn snapshot";
    ASSERT_GE(s[0], last);
    last = s[0];
  }
  writer.join();
  EXPECT_GT(fresh_reads, 0);
}

TEST(FixedRateRunner, CallsTheStepWithMeasuredTimeUntilStopped) {
  std::atomic<long> calls{0};
  std::atomic<bool> bad_dt{false};
  control::FixedRateRunner runner(1000.0, [&](double t, double dt) {
    if (!(dt > 0) || !(t >= 0)) bad_dt = true;
    ++calls;
  });
  runner.Start();
  // Wait (bounded) for some steps: this checks the plumbing, not the timing.
  for (int i = 0; i < 500 && calls < 50; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  runner.Stop();
  const long after_stop = calls;
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  EXPECT_GE(after_stop, 50);
  EXPECT_EQ(calls, after_stop);  // nothing runs after Stop
  EXPECT_FALSE(bad_dt);
  const auto stats = runner.stats();
  EXPECT_EQ(stats.steps, after_stop);
  EXPECT_GT(stats.mean_period, 0.0);
  EXPECT_THROW(control::FixedRateRunner(0.0, [](double, double) {}), Error);
}

}  // namespace
}  // namespace trocar
