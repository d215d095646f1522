#pragma once
/// @file
/// Real-time plumbing for teleoperation (thesis §3.4, made safe): a control thread at a fixed
/// rate (1 kHz or more) that integrates with the measured step time, and a wait-free triple
/// buffer through which it publishes consistent snapshots that a renderer (30–60 Hz) reads
/// without ever blocking it.

#include <atomic>
#include <cstdint>
#include <functional>
#include <thread>
#include <vector>

namespace trocar::control {

/// Single writer, single reader; neither ever waits for the other. The reader always gets the
/// latest complete value the writer published (or the previous one it read).
template <typename T>
class TripleBuffer {
 public:
  TripleBuffer() = default;
  explicit TripleBuffer(const T& initial) : buffers_{initial, initial, initial} {}

  /// Writer side.
  void Publish(const T& value) {
    buffers_[back_] = value;
    const std::uint8_t previous = middle_.exchange(back_ | kFresh, std::memory_order_acq_rel);
    back_ = previous & kIndex;
  }

  /// Reader side: true when the value is newer than the last one read.
  bool Read(T* out) {
    bool fresh = false;
    if (middle_.load(std::memory_order_acquire) & kFresh) {
      const std::uint8_t previous = middle_.exchange(front_, std::memory_order_acq_rel);
      front_ = previous & kIndex;
      fresh = true;
    }
    *out = buffers_[front_];
    return fresh;
  }

 private:
  static constexpr std::uint8_t kIndex = 0x3;
  static constexpr std::uint8_t kFresh = 0x4;
  T buffers_[3];
  std::atomic<std::uint8_t> middle_{1};
  std::uint8_t back_ = 0;   // writer's
  std::uint8_t front_ = 2;  // reader's
};

/// Timing of a FixedRateRunner's periods.
struct RunnerStats {
  long steps = 0;
  double mean_period = 0.0;        ///< s
  double p99_period_error = 0.0;   ///< s, 99th percentile of |measured period − nominal|
  double max_period_error = 0.0;   ///< s
  long overruns = 0;               ///< steps that started more than a whole period late
};

/// Calls `step(t, dt)` at a fixed rate in its own thread, t and dt measured on the steady clock
/// (dt is what the control law integrates with). Deadlines are absolute (start + k·period), so
/// lateness does not accumulate; a step that overruns is counted and the schedule resumes at the
/// next deadline.
class FixedRateRunner {
 public:
  using Step = std::function<void(double t, double dt)>;
  /// @throws trocar::Error for a non-positive rate.
  FixedRateRunner(double rate_hz, Step step);
  ~FixedRateRunner();
  FixedRateRunner(const FixedRateRunner&) = delete;
  FixedRateRunner& operator=(const FixedRateRunner&) = delete;

  void Start();
  /// Stops after the current step and joins the thread.
  void Stop();
  bool running() const { return running_.load(); }
  /// Valid after Stop().
  RunnerStats stats() const;

 private:
  void Loop();
  double period_;
  Step step_;
  std::thread thread_;
  std::atomic<bool> running_{false};
  std::atomic<bool> stop_{false};
  std::vector<double> period_errors_;
  std::vector<double> periods_;
  long overruns_ = 0;
};

}  // namespace trocar::control
