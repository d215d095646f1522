#include "progress.hpp"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <iostream>
#include <sstream>

namespace trocar::apps {

TerminalProgress::TerminalProgress(bool quiet) : enabled_(!quiet && isatty(STDERR_FILENO)) {}

TerminalProgress::~TerminalProgress() { Clear(); }

std::string TerminalProgress::Line(double fraction, const std::string& stage, double elapsed_s,
                                   int width) {
  std::ostringstream s;
  if (fraction >= 0.0) {
    const double f = std::clamp(fraction, 0.0, 1.0);
    const int bar = 20, filled = static_cast<int>(std::floor(f * bar));
    s << "[" << std::string(filled, '#') << std::string(bar - filled, ' ') << "] " << std::lround(f * 100)
      << " % ";
  }
  s << stage;
  if (fraction >= 0.03 && fraction < 1.0 && elapsed_s > 0.0) {
    const double left = elapsed_s * (1.0 - fraction) / fraction;
    s << ", about ";
    if (left < 90)
      s << std::lround(left) << " s";
    else
      s << std::lround(left / 60) << " min";
    s << " left";
  }
  std::string line = s.str();
  if (width > 3 && static_cast<int>(line.size()) > width) line = line.substr(0, width - 3) + "...";
  return line;
}

void TerminalProgress::Update(double fraction, const std::string& stage) {
  if (!enabled_) return;
  const Clock::time_point now = Clock::now();
  const std::string name = stage.substr(0, stage.find(':'));
  if (drawn_ && name == last_stage_ && now - last_ < std::chrono::milliseconds(100)) return;
  last_ = now;
  last_stage_ = name;
  const double elapsed = std::chrono::duration<double>(now - start_).count();
  // Carriage return, the line, then clear to the end of the line (ANSI EL).
  std::cerr << "\r" << Line(fraction, stage, elapsed) << "\x1b[K" << std::flush;
  drawn_ = true;
}

void TerminalProgress::Clear() {
  if (!enabled_ || !drawn_) return;
  std::cerr << "\r\x1b[K" << std::flush;
  drawn_ = false;
}

}  // namespace trocar::apps
