// Patient import benchmark: a case folder to a cached model, cold (rebuilt) and cached, each in
// its own child process so that its peak memory (max RSS) is its own. Target (issue 5): LIDC2
// under 20 s cold and under 1 s cached on a 2-core machine.
//   import_bench [case_dir=patients/lidc2] [repetitions=3]
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <iostream>
#include <string>
#include <vector>

#include "common/error.hpp"
#include "patient/patient_model.hpp"

namespace {

struct Run {
  double seconds = 0.0;
  double peak_mib = 0.0;
  bool ok = false;
};

Run Measure(const std::string& dir, bool cached) {
  int pipe_fd[2];
  if (pipe(pipe_fd) != 0) return {};
  const pid_t pid = fork();
  if (pid == 0) {
    close(pipe_fd[0]);
    double seconds = -1.0;
    try {
      trocar::patient::ImportOptions options;
      options.use_cache = cached;
      const auto t0 = std::chrono::steady_clock::now();
      const auto model = trocar::patient::ImportPatient(dir, options);
      seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (model.from_cache != cached) seconds = -2.0;
    } catch (const std::exception& e) {
      std::cerr << "error: " << e.what() << "\n";
    }
    if (write(pipe_fd[1], &seconds, sizeof seconds) != sizeof seconds) _exit(2);
    _exit(0);
  }
  close(pipe_fd[1]);
  Run run;
  double seconds = -1.0;
  const bool got = read(pipe_fd[0], &seconds, sizeof seconds) == sizeof seconds;
  close(pipe_fd[0]);
  int status = 0;
  struct rusage usage {};
  wait4(pid, &status, 0, &usage);
  run.ok = got && seconds >= 0.0 && WIFEXITED(status) && WEXITSTATUS(status) == 0;
  run.seconds = seconds;
  run.peak_mib = usage.ru_maxrss / 1024.0;  // KiB on Linux
  return run;
}

}  // namespace

int main(int argc, char** argv) {
  const std::string dir = argc > 1 ? argv[1] : std::string(TROCAR_SOURCE_DIR) + "/patients/lidc2";
  const int repetitions = argc > 2 ? std::max(1, std::atoi(argv[2])) : 3;
  std::printf("import %s, %d repetitions each (child processes; peak = max RSS)\n", dir.c_str(),
              repetitions);
  for (const bool cached : {false, true}) {
    std::vector<double> seconds, peaks;
    for (int r = 0; r < repetitions; ++r) {
      const Run run = Measure(dir, cached);
      if (!run.ok) {
        std::fprintf(stderr, "import_bench: %s import failed (seconds %.0f)\n",
                     cached ? "cached" : "cold", run.seconds);
        return 1;
      }
      seconds.push_back(run.seconds);
      peaks.push_back(run.peak_mib);
    }
    std::sort(seconds.begin(), seconds.end());
    std::printf("  %-6s median %7.3f s  (min %.3f, max %.3f)  peak memory %.0f MiB  target %s\n",
                cached ? "cached" : "cold", seconds[seconds.size() / 2], seconds.front(),
                seconds.back(), *std::max_element(peaks.begin(), peaks.end()),
                cached ? "< 1 s" : "< 20 s");
  }
  return 0;
}
