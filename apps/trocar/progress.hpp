#pragma once
/// @file
/// A one-line progress display for the long commands (`plan`, `verify`, `bench`, `import`; issue
/// #43 item 11): the stage, the share done and the time left, redrawn in place on standard error
/// at most ten times a second. Shown only when standard error is a terminal and the command is
/// not quiet: a log or a pipe gets none of it. The line is cleared when the work is done (or the
/// object goes), so that the results print on a clean line.

#include <chrono>
#include <string>

namespace trocar::apps {

class TerminalProgress {
 public:
  /// Enabled when `quiet` is false and standard error is a terminal.
  explicit TerminalProgress(bool quiet = false);
  ~TerminalProgress();
  TerminalProgress(const TerminalProgress&) = delete;
  TerminalProgress& operator=(const TerminalProgress&) = delete;

  bool enabled() const { return enabled_; }
  /// `fraction` of the whole command done (0..1; negative: unknown, no bar or time left).
  /// Drawn at most every 100 ms, except that a new stage (the text before its first ':') is
  /// drawn at once: a short stage is still seen, on a fast machine or a loaded one.
  void Update(double fraction, const std::string& stage);
  /// Removes the line (drawn again by the next Update).
  void Clear();

  /// The line drawn for `fraction` and `stage` after `elapsed_s` seconds, `width` columns at
  /// most: "[#######         ]  42 % global direct-l: 500 of 1200 evaluations, about 12 s left".
  /// The time left is shown once 3 % is done. Exposed for the tests.
  static std::string Line(double fraction, const std::string& stage, double elapsed_s, int width = 100);

 private:
  using Clock = std::chrono::steady_clock;
  bool enabled_ = false;
  bool drawn_ = false;
  Clock::time_point start_ = Clock::now(), last_{};
  std::string last_stage_;  // the stage (before its first ':') drawn last
};

}  // namespace trocar::apps
