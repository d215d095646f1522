#pragma once
// Shared by the fuzz targets: each target hands libFuzzer's bytes to one reader, through a file
// when the reader takes a path. trocar::Error is the expected outcome of bad input; any other
// exception ("internal error" for a user) aborts, so libFuzzer records it as a finding, as it
// does crashes, sanitizer reports, leaks, timeouts and memory beyond -rss_limit_mb.
#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <exception>
#include <filesystem>
#include <fstream>
#include <string>

#include "common/error.hpp"

namespace trocar::fuzz {

/// A folder of this process's own (several fuzzers may run at once), made on first use.
/// TROCAR_FUZZ_DIR names it outright: the paths a reader sees (and compares, which libFuzzer
/// records) are then the same from run to run, so a seeded run of a fixed count repeats.
inline const std::string& WorkDir() {
  static const std::string dir = [] {
    if (const char* fixed = std::getenv("TROCAR_FUZZ_DIR"); fixed != nullptr && *fixed != '\0') {
      std::filesystem::create_directories(fixed);
      return std::string(fixed);
    }
    const char* base = std::getenv("TMPDIR");
    std::string d = std::string(base != nullptr ? base : "/tmp") + "/trocar-fuzz-" +
                    std::to_string(::getpid());
    std::filesystem::create_directories(d);
    return d;
  }();
  return dir;
}

/// Writes `size` bytes to WorkDir()/name and returns its path.
inline std::string WriteInput(const std::string& name, const uint8_t* data, size_t size) {
  const std::string path = WorkDir() + "/" + name;
  std::filesystem::create_directories(std::filesystem::path(path).parent_path());
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
  return path;
}

/// Runs `f`; bad input must end in trocar::Error, never in another exception.
template <typename F>
void Expect(F&& f) {
  try {
    f();
  } catch (const trocar::Error&) {
    // The reader refused the input by name: the expected outcome.
  } catch (const std::exception& e) {
    std::fprintf(stderr, "FINDING: exception other than trocar::Error: %s\n", e.what());
    std::abort();
  }
}

}  // namespace trocar::fuzz
