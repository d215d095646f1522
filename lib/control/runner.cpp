#include "control/runner.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>

#include "common/error.hpp"

namespace trocar::control {

FixedRateRunner::FixedRateRunner(double rate_hz, Step step) : step_(std::move(step)) {
  TROCAR_THROW_UNLESS(std::isfinite(rate_hz) && rate_hz > 0,
                      "control runner: rate " << rate_hz << " Hz must be positive");
  period_ = 1.0 / rate_hz;
}

FixedRateRunner::~FixedRateRunner() { Stop(); }

void FixedRateRunner::Start() {
  if (running_.exchange(true)) return;
  stop_ = false;
  period_errors_.clear();
  periods_.clear();
  overruns_ = 0;
  thread_ = std::thread([this] { Loop(); });
}

void FixedRateRunner::Stop() {
  stop_ = true;
  if (thread_.joinable()) thread_.join();
  running_ = false;
}

void FixedRateRunner::Loop() {
  using Clock = std::chrono::steady_clock;
  const auto period = std::chrono::duration_cast<Clock::duration>(std::chrono::duration<double>(period_));
  const Clock::time_point start = Clock::now();
  Clock::time_point previous = start;
  Clock::time_point deadline = start;
  period_errors_.reserve(1 << 16);
  periods_.reserve(1 << 16);
  while (!stop_.load(std::memory_order_relaxed)) {
    deadline += period;
    std::this_thread::sleep_until(deadline);
    const Clock::time_point now = Clock::now();
    if (now - deadline > period) {
      ++overruns_;
      deadline = now;  // resume the schedule from here rather than bursting to catch up
    }
    const double dt = std::chrono::duration<double>(now - previous).count();
    const double t = std::chrono::duration<double>(now - start).count();
    previous = now;
    periods_.push_back(dt);
    period_errors_.push_back(std::abs(dt - period_));
    step_(t, dt);
  }
}

RunnerStats FixedRateRunner::stats() const {
  RunnerStats s;
  s.steps = static_cast<long>(periods_.size());
  s.overruns = overruns_;
  if (periods_.empty()) return s;
  double sum = 0.0;
  for (double p : periods_) sum += p;
  s.mean_period = sum / static_cast<double>(periods_.size());
  std::vector<double> errors = period_errors_;
  const std::size_t k = static_cast<std::size_t>(0.99 * static_cast<double>(errors.size() - 1));
  std::nth_element(errors.begin(), errors.begin() + static_cast<long>(k), errors.end());
  s.p99_period_error = errors[k];
  s.max_period_error = *std::max_element(period_errors_.begin(), period_errors_.end());
  return s;
}

}  // namespace trocar::control
