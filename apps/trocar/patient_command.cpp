// trocar phantom: generate a thorax phantom case.
#include <filesystem>
#include <iostream>
#include <memory>

#include "apps/trocar/commands.hpp"
#include "common/file_util.hpp"
#include "common/plot.hpp"
#include "patient/phantom.hpp"

namespace trocar::apps {
namespace {

struct PhantomOptions {
  std::string out;
  patient::PhantomParameters p;
  bool ras = false;
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
  auto blit = [&](const patient::SliceImage& s, int x0) {
    for (int r = 0; r < s.height; ++r) {
      std::copy_n(&s.rgb[3 * static_cast<std::size_t>(r) * s.width], 3 * s.width,
                  &image.rgb[3 * (static_cast<std::size_t>(r) * image.width + x0)]);
    }
  };
  blit(axial, 0);
  blit(coronal, axial.width + 10);
  WriteFileAtomically(path, EncodePng(image));
}

void RunPhantom(const PhantomOptions& o) {
  const patient::Phantom ph = patient::GeneratePhantom(o.p);
  patient::WritePhantomCase(ph, o.out, o.ras);
  WritePreview(ph, JoinPath(o.out, "preview.png"));
  const Eigen::Vector3d spacing = ph.ct.spacing() * 1e3;
  std::cout << "phantom (seed " << o.p.seed << "): " << ph.ct.size.x() << " x " << ph.ct.size.y()
            << " x " << ph.ct.size.z() << " voxels of " << spacing.x() << " mm, HU; "
            << ph.truth.ribs.size() << " ribs, " << ph.truth.intercostal_spaces.size()
            << " intercostal spaces, LAD " << ph.truth.lad.size() << " points, LIMA "
            << ph.truth.lima.size() << " points\n";
  for (const char* file : {"ct.nrrd", "patient.yaml", "truth.json", "markups/LAD.mrk.json",
                           "markups/LIMA.mrk.json", "markups/intercostal_left.mrk.json", "preview.png"}) {
    std::cout << "  " << JoinPath(o.out, file) << "\n";
  }
}

}  // namespace

void AddPatientCommands(CLI::App* app) {
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
  cmd->add_flag("--ras", o->ras, "write the CT with a RAS header (default LPS)");
  cmd->callback([o]() { RunPhantom(*o); });
}

}  // namespace trocar::apps
