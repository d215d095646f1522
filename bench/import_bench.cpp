// Patient import benchmark: a case folder to a cached model, cold (rebuilt) and cached, each in
// its own child process so that its peak memory (max RSS) is its own; the surface stage alone
// beside the total. Targets (issue 17): a 512×512×300 chest CT cold under 15 s and under 2 GB
// peak on 2 cores, cached under 1 s; (issue 5) LIDC2 under 20 s cold.
//   import_bench                      LIDC2, the bundled phantom, a 512×512×300 phantom, the
//                                     same as an 8-bit window, and on a CT table
//   import_bench CASE_DIR [REPS=3]    one case
// The 512×512×300 case is generated once into out/bench/phantom-512x512x300 (a 38 cm field of
// view, 0.74 mm in plane, 1.2 mm slices: clinical spacing); its windowed copy (a 400-wide window
// at 40 HU to 0-255, `units: raw`, spaces from the rib cage's layer) into out/bench/windowed-512.
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <string>
#include <vector>

#include "common/error.hpp"
#include "patient/patient_model.hpp"
#include "patient/phantom.hpp"
#include "patient/segmentation.hpp"
#include "patient/volume.hpp"

namespace {

struct Run {
  double seconds = 0.0;
  double surfaces = 0.0;  ///< the surface stage (cold runs)
  double peak_mib = 0.0;
  bool ok = false;
};

Run Measure(const std::string& dir, bool cached) {
  int pipe_fd[2];
  if (pipe(pipe_fd) != 0) return {};
  const pid_t pid = fork();
  if (pid == 0) {
    close(pipe_fd[0]);
    double out[2] = {-1.0, 0.0};
    try {
      trocar::patient::ImportOptions options;
      options.use_cache = cached;
      const auto t0 = std::chrono::steady_clock::now();
      const auto imported = trocar::patient::ImportCase(dir, options);
      out[0] = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      if (imported.report.from_cache != cached) out[0] = -2.0;
      for (const auto& [stage, seconds] : imported.report.timings) {
        if (stage == "surfaces") out[1] = seconds;
      }
    } catch (const std::exception& e) {
      std::cerr << "error: " << e.what() << "\n";
    }
    if (write(pipe_fd[1], out, sizeof out) != sizeof out) _exit(2);
    _exit(0);
  }
  close(pipe_fd[1]);
  Run run;
  double out[2] = {-1.0, 0.0};
  const bool got = read(pipe_fd[0], out, sizeof out) == sizeof out;
  close(pipe_fd[0]);
  int status = 0;
  struct rusage usage {};
  wait4(pid, &status, 0, &usage);
  run.ok = got && out[0] >= 0.0 && WIFEXITED(status) && WEXITSTATUS(status) == 0;
  run.seconds = out[0];
  run.surfaces = out[1];
  run.peak_mib = usage.ru_maxrss / 1024.0;  // KiB on Linux
  return run;
}

// Runs `make` in a child process: the bench's own process never starts OpenMP's threads (a child
// forked after them may hang in its first parallel region; resampling a case is parallel).
bool InChild(const std::function<void()>& make) {
  std::fflush(stdout);
  const pid_t pid = fork();
  if (pid == 0) {
    int code = 0;
    try {
      make();
    } catch (const std::exception& e) {
      std::cerr << "import_bench: " << e.what() << "\n";
      code = 1;
    }
    std::fflush(stdout);
    _exit(code);
  }
  int status = 0;
  waitpid(pid, &status, 0);
  return pid > 0 && WIFEXITED(status) && WEXITSTATUS(status) == 0;
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

bool Bench(const std::string& dir, int repetitions) {
  std::printf("%s (%d repetitions each; child processes; peak = max RSS)\n", dir.c_str(), repetitions);
  for (const bool cached : {false, true}) {
    std::vector<double> seconds, surfaces, peaks;
    for (int r = 0; r < repetitions; ++r) {
      const Run run = Measure(dir, cached);
      if (!run.ok) {
        std::fprintf(stderr, "import_bench: %s: %s import failed (seconds %.0f)\n", dir.c_str(),
                     cached ? "cached" : "cold", run.seconds);
        return false;
      }
      seconds.push_back(run.seconds);
      surfaces.push_back(run.surfaces);
      peaks.push_back(run.peak_mib);
    }
    std::printf("  %-6s median %7.3f s (min %.3f, max %.3f)", cached ? "cached" : "cold",
                Median(seconds), *std::min_element(seconds.begin(), seconds.end()),
                *std::max_element(seconds.begin(), seconds.end()));
    if (!cached) std::printf("  surfaces %6.3f s", Median(surfaces));
    std::printf("  peak %5.0f MiB\n", *std::max_element(peaks.begin(), peaks.end()));
  }
  return true;
}

// A phantom CT of 512×512×300 voxels at clinical spacing, generated once; `on_table`: the
// patient's back pressed 4 mm onto a CT table (the table left out of the body on import).
std::string ClinicalPhantomCase(bool on_table = false) {
  const std::string dir = std::string(TROCAR_SOURCE_DIR) + "/out/bench/phantom-512x512x300" +
                          (on_table ? "-on-table" : "");
  if (!std::filesystem::exists(dir + "/patient.yaml") && !InChild([&] {
        trocar::patient::PhantomParameters p;
        if (on_table) p.table_gap = -0.004;
        p.field_of_view = 0.38;
        p.voxel_size = p.field_of_view / 512;
        p.slice_spacing = 0.0012;
        p.length = 0.36;
        const auto phantom = trocar::patient::GeneratePhantom(p);
        std::printf("generated %s: %d x %d x %d voxels\n", dir.c_str(), phantom.ct.size.x(),
                    phantom.ct.size.y(), phantom.ct.size.z());
        trocar::patient::WritePhantomCase(phantom, dir);
      }))
    throw trocar::Error("could not generate " + dir);
  return dir;
}

// The clinical phantom's CT as an 8-bit window (400 wide at 40 HU), `units: raw`, without
// annotated spaces: the windowed path (convex body fill, the rib cage's layer), generated once.
std::string WindowedClinicalCase(const std::string& clinical) {
  const std::string dir = std::string(TROCAR_SOURCE_DIR) + "/out/bench/windowed-512";
  if (!std::filesystem::exists(dir + "/patient.yaml") && !InChild([&] {
        trocar::patient::Volume ct = trocar::patient::LoadVolume(clinical + "/ct.nrrd");
        for (float& v : ct.values) v = std::clamp((v + 160.0f) / 400.0f * 255.0f, 0.0f, 255.0f);
        ct.hounsfield = false;
        std::filesystem::create_directories(dir + "/markups");
        trocar::patient::WriteNrrd(ct, dir + "/ct.nrrd");
        std::filesystem::copy_file(clinical + "/markups/LAD.mrk.json",
                                   dir + "/markups/LAD.mrk.json",
                                   std::filesystem::copy_options::overwrite_existing);
        std::ofstream(dir + "/patient.yaml.tmp")
            << "name: windowed-512\nct: ct.nrrd\nunits: raw\nthresholds: {body: 20, bone: 200}\n"
            << "heart: {contrast: false}\n"
            << "targets:\n  - {name: LAD, markups: markups/LAD.mrk.json, surface: skin}\n"
            << "intercostal: {left: true}\n";
        std::filesystem::rename(dir + "/patient.yaml.tmp", dir + "/patient.yaml");
        std::printf("generated %s from %s\n", dir.c_str(), clinical.c_str());
      }))
    throw trocar::Error("could not generate " + dir);
  return dir;
}

// The clinical phantom turned 12 degrees about its long axis, generated once:
// - "rolled-512": the anatomy turned (right side up) on an axis-aligned grid; the import measures
//   the roll and sorts it turned upright;
// - "oblique-512": the anatomy where it was, on a grid turned from the patient's axes (an oblique
//   header); the import resamples the grid along them.
// Either way a second segmentation, on a resampled grid.
std::string TurnedClinicalCase(const std::string& clinical, bool oblique) {
  const std::string name = oblique ? "oblique-512" : "rolled-512";
  const std::string dir = std::string(TROCAR_SOURCE_DIR) + "/out/bench/" + name;
  if (!std::filesystem::exists(dir + "/patient.yaml") && !InChild([&] {
        const trocar::patient::Volume ct = trocar::patient::LoadVolume(clinical + "/ct.nrrd");
        const Eigen::Vector3d centre =
            ct.PatientPoint(0.5 * (ct.size.x() - 1), 0.5 * (ct.size.y() - 1), 0.0);
        const Eigen::Isometry3d X_turn =
            Eigen::Translation3d(centre) *
            Eigen::AngleAxisd(12.0 * M_PI / 180.0, Eigen::Vector3d::UnitZ()) *
            Eigen::Translation3d(-centre);
        // Resampled onto a grid along the turned frame. Read as the patient frame: the anatomy
        // turned on an axis-aligned grid; its geometry carried back: the anatomy where it was,
        // on turned rows.
        trocar::patient::Volume turned = trocar::patient::ResampleTurned(ct, X_turn, -1000.0f);
        if (oblique) trocar::patient::MoveVolumeFrame(X_turn.inverse(), &turned);
        std::filesystem::create_directories(dir);
        trocar::patient::WriteNrrd(turned, dir + "/ct.nrrd");
        std::ofstream(dir + "/patient.yaml.tmp")
            << "name: " << name << "\nct: ct.nrrd\nunits: hounsfield\nintercostal: {left: true}\n";
        std::filesystem::rename(dir + "/patient.yaml.tmp", dir + "/patient.yaml");
        std::printf("generated %s from %s: %d x %d x %d voxels\n", dir.c_str(), clinical.c_str(),
                    turned.size.x(), turned.size.y(), turned.size.z());
      }))
    throw trocar::Error("could not generate " + dir);
  return dir;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    if (argc > 1) return Bench(argv[1], argc > 2 ? std::max(1, std::atoi(argv[2])) : 3) ? 0 : 1;
    const std::string source = TROCAR_SOURCE_DIR;
    bool ok = Bench(source + "/patients/lidc2", 3);
    ok = Bench(source + "/patients/phantom-default", 3) && ok;
    const std::string clinical = ClinicalPhantomCase();
    ok = Bench(clinical, 3) && ok;
    ok = Bench(WindowedClinicalCase(clinical), 3) && ok;
    ok = Bench(ClinicalPhantomCase(true), 3) && ok;
    ok = Bench(TurnedClinicalCase(clinical, false), 3) && ok;
    ok = Bench(TurnedClinicalCase(clinical, true), 3) && ok;
    std::printf("targets: 512x512x300 cold < 15 s and < 2048 MiB, cached < 1 s; LIDC2 cold < 20 s\n");
    return ok ? 0 : 1;
  } catch (const std::exception& e) {
    std::cerr << "import_bench: " << e.what() << "\n";
    return 1;
  }
}
