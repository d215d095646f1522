// trocar phantom: generate a thorax phantom case.
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <memory>

#include "apps/trocar/commands.hpp"
#include "apps/trocar/progress.hpp"
#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/image.hpp"
#include "patient/patient_model.hpp"
#include "patient/phantom.hpp"

namespace trocar::apps {
namespace {

struct PhantomOptions {
  std::string out;
  patient::PhantomParameters p;
  bool ras = false;
  bool dicom = false;
  bool force = false;
};

// Axial slice at the heart and a coronal slice through it, side by side, soft-tissue window.
void WritePreview(const patient::Phantom& ph, const std::string& path) {
  const Eigen::Vector3d ijk = ph.ct.IndexOf(ph.truth.heart_centre);
  const auto axial = patient::RenderSlice(ph.ct, 2, static_cast<int>(std::lround(ijk.z())), 40, 1200);
  const auto coronal = patient::RenderSlice(ph.ct, 1, static_cast<int>(std::lround(ijk.y())), 40, 1200);
  Image image;
  image.width = axial.width + 10 + coronal.width;
  image.height = std::max(axial.height, coronal.height);
  image.rgb.assign(3 * static_cast<std::size_t>(image.width) * image.height, 0);
  auto blit = [&](const Image& s, int x0) {
    for (int r = 0; r < s.height; ++r) {
      std::copy_n(&s.rgb[3 * static_cast<std::size_t>(r) * s.width], 3 * s.width,
                  &image.rgb[3 * (static_cast<std::size_t>(r) * image.width + x0)]);
    }
  };
  blit(axial, 0);
  blit(coronal, axial.width + 10);
  WritePng(image, path);
}

void RunPhantom(const PhantomOptions& o) {
  // Checked before the minutes of generation, and never over a case someone may have edited.
  if (!o.force) {
    for (const char* name : {"patient.yaml", "ct.nrrd", "ct", "markups"}) {
      const std::string existing = JoinPath(o.out, name);
      std::error_code ec;
      TROCAR_THROW_UNLESS(!std::filesystem::exists(existing, ec),
                          o.out << ": already holds a case (" << existing
                                << "); choose another --out, or add --force to overwrite it");
    }
  }
  {
    std::error_code ec;
    TROCAR_THROW_UNLESS(!std::filesystem::exists(o.out, ec) || std::filesystem::is_directory(o.out, ec),
                        o.out << ": exists and is not a folder");
  }
  const patient::Phantom ph = patient::GeneratePhantom(o.p);
  const patient::CtFormat format = o.dicom ? patient::CtFormat::kDicom
                                  : o.ras  ? patient::CtFormat::kNrrdRas
                                           : patient::CtFormat::kNrrdLps;
  patient::WritePhantomCase(ph, o.out, format);
  WritePreview(ph, JoinPath(o.out, "preview.png"));
  const Eigen::Vector3d spacing = ph.ct.spacing() * 1e3;
  std::cout << "phantom (seed " << o.p.seed << "): " << ph.ct.size.x() << " x " << ph.ct.size.y()
            << " x " << ph.ct.size.z() << " voxels of " << spacing.x() << " x " << spacing.y() << " x " << spacing.z() << " mm, HU; "
            << ph.truth.ribs.size() << " ribs, " << ph.truth.intercostal_spaces.size()
            << " intercostal spaces, LAD " << ph.truth.lad.size() << " points, LIMA "
            << ph.truth.lima.size() << " points\n";
  std::cout << "  " << JoinPath(o.out, o.dicom ? "ct/ (DICOM series, " + std::to_string(ph.ct.size.z()) + " slices)" : "ct.nrrd") << "\n";
  for (const char* file : {"patient.yaml", "truth.json", "markups/LAD.mrk.json",
                           "markups/LIMA.mrk.json", "markups/intercostal_left.mrk.json", "preview.png"}) {
    std::cout << "  " << JoinPath(o.out, file) << "\n";
  }
}

struct ImportCommandOptions {
  std::string case_dir;
  bool rebuild = false;
  bool no_cache = false;
};

void RunImport(const ImportCommandOptions& o) {
  patient::ImportOptions options;
  options.use_cache = !o.rebuild && !o.no_cache;
  options.write_cache = !o.no_cache;
  TerminalProgress bar;
  options.progress = [&bar](const std::string& stage) { bar.Update(-1.0, "importing: " + stage); };
  const patient::ImportedPatient imported = patient::ImportCase(o.case_dir, options);
  bar.Clear();
  const patient::PatientModel& m = *imported.model;
  const patient::ImportReport& report = imported.report;
  std::cout << std::fixed << std::setprecision(1);
  std::cout << "patient " << m.name << (report.from_cache ? " (from cache)" : "") << "\n"
            << "  CT: " << m.ct_source << "\n";
  const Eigen::Vector3d extent = (m.body_max_P - m.body_min_P) * 1e3;
  std::cout << "  body: " << extent.x() << " x " << extent.y() << " x " << extent.z()
            << " mm (left-right, front-back, head-foot)\n";
  std::cout << "  structures (" << m.triangle_count() << " triangles):\n";
  for (const auto& s : m.structures) {
    std::cout << "    " << std::left << std::setw(8) << s.name << std::right << std::setw(8)
              << s.mesh.triangles.size() << " triangles (from " << s.contoured_triangles
              << "), " << s.volume * 1e6 << " ml\n";
  }
  std::cout << "  targets:\n";
  for (const auto& t : m.targets) {
    double length = 0.0;
    for (std::size_t i = 1; i < t.points.size(); ++i) length += (t.points[i] - t.points[i - 1]).norm();
    std::cout << "    " << t.name << ": " << t.points.size() << " points, " << length * 1e3
              << " mm long, normals from " << t.normals_from << "\n";
  }
  std::cout << "  port candidates: " << m.port_candidates.size();
  if (!m.port_candidates.empty()) std::cout << " (" << m.port_candidates.front().source << ")";
  std::cout << "\n";
  for (const auto& c : m.port_candidates) std::cout << "    " << c.name << ": " << c.skin.size() << " points\n";
  for (const auto& line : report.checks) std::cout << "  check: " << line << "\n";
  for (const auto& line : report.warnings) std::cout << "  warning: " << line << "\n";
  std::cout << "  pose: left side up " << m.left_side_up * 180.0 / M_PI << " deg, table top at "
            << m.table.height * 1e3
            << " mm (the case's; trocar plan sets each plan's within plan.table_height)\n";
  std::cout << std::setprecision(3) << "  timings (s):";
  double total = 0.0;
  for (const auto& [stage, seconds] : report.timings) {
    std::cout << " " << stage << " " << seconds << ";";
    total += seconds;
  }
  std::cout << " total " << total << "\n";
  if (!report.cache_error.empty()) {
    std::cout << "  cache: not written: " << report.cache_error << "\n";
  } else if (!o.no_cache) {
    std::cout << "  cache: " << JoinPath(m.case_dir, "cache") << "\n";
  }
  // A model without port candidates cannot be planned on: say why, and exit non-zero.
  if (m.port_candidates.empty()) {
    for (const auto& w : report.warnings) {
      if (w.rfind("no port candidates", 0) == 0) throw trocar::Error(JoinPath(m.case_dir, "patient.yaml") + ": " + w);
    }
    throw trocar::Error(JoinPath(m.case_dir, "patient.yaml") + ": no port candidates");
  }
}

}  // namespace

void AddPatientCommands(CLI::App* app) {
  {
    auto o = std::make_shared<ImportCommandOptions>();
    CLI::App* cmd = app->add_subcommand(
        "import", "Build (or load from its cache) the patient model of a case folder and summarise it");
    cmd->add_option("case", o->case_dir, "case folder holding patient.yaml (e.g. patients/phantom-default)")
        ->required();
    cmd->add_flag("--rebuild", o->rebuild, "ignore the cache and rebuild it");
    cmd->add_flag("--no-cache", o->no_cache, "neither read nor write the cache");
    cmd->callback([o]() { RunImport(*o); });
  }
  auto o = std::make_shared<PhantomOptions>();
  CLI::App* cmd = app->add_subcommand(
      "phantom", "Generate a thorax phantom case: CT in HU, 3D Slicer markups, truth, patient.yaml");
  cmd->add_option("--out", o->out, "case folder to write")->required();
  cmd->add_option("--seed", o->p.seed, "anatomical variation seed")->capture_default_str();
  cmd->add_option("--body-width", o->p.body_width, "left-right width at the skin (m)")->capture_default_str();
  cmd->add_option("--body-depth", o->p.body_depth, "front-back depth at the skin (m)")->capture_default_str();
  cmd->add_option("--length", o->p.length, "superior-inferior extent (m)")->capture_default_str();
  cmd->add_option("--fat", o->p.fat_thickness, "subcutaneous fat thickness (m)")->capture_default_str();
  cmd->add_option("--ribs", o->p.ribs_per_side, "ribs per side")->capture_default_str();
  cmd->add_option("--rib-spacing", o->p.rib_spacing, "distance between ribs at the back (m)")->capture_default_str();
  cmd->add_option("--heart-scale", o->p.heart_scale, "heart size factor")->capture_default_str();
  cmd->add_option("--voxel", o->p.voxel_size, "voxel size (m)")->capture_default_str();
  cmd->add_option("--slice", o->p.slice_spacing, "axial slice spacing (m; 0: the voxel size)")->capture_default_str();
  cmd->add_option("--fov", o->p.field_of_view, "square in-plane field of view (m; 0: the body and 2 cm around it)")->capture_default_str();
  cmd->add_option("--wall", o->p.wall_thickness, "chest-wall muscle outside the ribs (m)")->capture_default_str();
  cmd->add_flag("--ribs-reach-spine", o->p.ribs_reach_spine, "ribs meet the vertebral bodies, as real ribs do");
  cmd->add_flag("--shoulders", o->p.shoulders,
                "shoulder blades, collarbones and upper arms (needs --wall 0.02 or more)");
  cmd->add_option(
      "--table-gap", o->p.table_gap,
      "a CT table under the back, its top this far behind the back (m; negative presses "
      "the back flat onto it; default: no table)");
  cmd->add_flag("--force", o->force, "overwrite the case already in --out (its patient.yaml too)");
  cmd->add_flag("--ras", o->ras, "write the CT with a RAS header (default LPS)");
  cmd->add_flag("--dicom", o->dicom, "write the CT as a DICOM series folder ct/ instead of ct.nrrd")
      ->excludes("--ras");
  cmd->callback([o]() { RunPhantom(*o); });
}

}  // namespace trocar::apps
