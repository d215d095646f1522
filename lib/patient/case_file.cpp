#include "patient/case_file.hpp"

#include <cctype>
#include <tuple>
#include <cmath>
#include <filesystem>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/yaml_util.hpp"

namespace trocar::patient {

namespace {

// A quantity with an optional unit suffix ("12.5 mm", "1.2 cm", "0.0125"; "8 mmHg", "8"): the
// value in `base` units (m, mmHg). A unit not in `units` is an error naming it.
double Quantity(const YamlReader& y, const YAML::Node& node, const std::string& path,
                const std::vector<std::pair<std::string, double>>& units) {
  TROCAR_THROW_UNLESS(node.IsScalar(), y.Where(node, path) << ": expected a number with a unit");
  std::string text = node.Scalar();
  double scale = 1.0;
  for (const auto& [unit, factor] : units) {
    if (text.size() > unit.size() && text.compare(text.size() - unit.size(), unit.size(), unit) == 0) {
      text = text.substr(0, text.size() - unit.size());
      scale = factor;
      break;
    }
  }
  std::size_t used = 0;
  double value = 0.0;
  try {
    value = std::stod(text, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  while (used < text.size() && std::isspace(static_cast<unsigned char>(text[used]))) ++used;
  std::string expected;
  for (const auto& u : units) expected += (expected.empty() ? "" : ", ") + u.first;
  TROCAR_THROW_UNLESS(used == text.size() && used > 0 && std::isfinite(value),
                      y.Where(node, path) << ": '" << node.Scalar()
                                          << "' is not a number with a unit (" << expected << ")");
  return value * scale;
}

// operation: none | {co2: 8 mmHg, lung: isolated|ventilated, heart_shift: 12.5 mm,
//                    heart_shift_range: [10 mm, 15 mm]} (docs/operative-state.md).
void ReadOperation(const YamlReader& y, const YAML::Node& o, OperativeState* state) {
  if (o.IsScalar()) {
    TROCAR_THROW_UNLESS(o.Scalar() == "none" || o.Scalar() == "operative",
                        y.Where(o, "operation") << ": '" << o.Scalar()
                                                << "': expected none (plan in the CT's state), "
                                                   "operative, or a map of the state's values");
    state->applied = o.Scalar() != "none";
    return;
  }
  y.ExpectMap(o, "operation", {"co2", "lung", "heart_shift", "heart_shift_range"});
  const std::vector<std::pair<std::string, double>> length = {{"mm", 1e-3}, {"cm", 1e-2}, {"m", 1.0}};
  if (o["co2"]) {
    state->co2_mmhg = Quantity(y, o["co2"], "operation.co2", {{"mmHg", 1.0}});
    TROCAR_THROW_UNLESS(state->co2_mmhg >= 0.0 && state->co2_mmhg <= kMaxCo2Mmhg,
                        y.Where(o["co2"], "operation.co2")
                            << ": " << state->co2_mmhg << " mmHg is outside 0-" << kMaxCo2Mmhg
                            << " mmHg (robotic TECAB insufflates 5-12 mmHg; 0: no CO2)");
  }
  if (o["lung"]) {
    const std::string lung = y.String(o["lung"], "operation.lung");
    TROCAR_THROW_UNLESS(lung == "isolated" || lung == "ventilated",
                        y.Where(o["lung"], "operation.lung")
                            << ": '" << lung << "': expected isolated (one-lung ventilation, the "
                               "left lung isolated) or ventilated");
    state->left_lung_isolated = lung == "isolated";
  }
  auto shift = [&](const YAML::Node& n, const std::string& path) {
    const double v = Quantity(y, n, path, length);
    TROCAR_THROW_UNLESS(v >= 0.0 && v <= kMaxHeartShift,
                        y.Where(n, path) << ": " << v * 1e3 << " mm is outside 0-"
                                         << kMaxHeartShift * 1e3 << " mm");
    return v;
  };
  if (o["heart_shift_range"]) {
    const YAML::Node r = o["heart_shift_range"];
    TROCAR_THROW_UNLESS(r.IsSequence() && r.size() == 2,
                        y.Where(r, "operation.heart_shift_range")
                            << ": expected [min, max], e.g. [10 mm, 15 mm]");
    state->heart_shift_min = shift(r[0], "operation.heart_shift_range[0]");
    state->heart_shift_max = shift(r[1], "operation.heart_shift_range[1]");
    TROCAR_THROW_UNLESS(state->heart_shift_min <= state->heart_shift_max,
                        y.Where(r, "operation.heart_shift_range")
                            << ": min " << state->heart_shift_min * 1e3 << " mm > max "
                            << state->heart_shift_max * 1e3 << " mm");
    if (!o["heart_shift"])
      state->heart_shift = 0.5 * (state->heart_shift_min + state->heart_shift_max);
  }
  if (o["heart_shift"]) {
    state->heart_shift = shift(o["heart_shift"], "operation.heart_shift");
    if (!o["heart_shift_range"]) {
      // A planned value alone: the range keeps its width around it.
      const double half = 0.5 * (state->heart_shift_max - state->heart_shift_min);
      state->heart_shift_min = std::max(0.0, state->heart_shift - half);
      state->heart_shift_max = std::min(kMaxHeartShift, state->heart_shift + half);
    }
    TROCAR_THROW_UNLESS(state->heart_shift >= state->heart_shift_min - 1e-12 &&
                            state->heart_shift <= state->heart_shift_max + 1e-12,
                        y.Where(o["heart_shift"], "operation.heart_shift")
                            << ": " << state->heart_shift * 1e3
                            << " mm is outside its range heart_shift_range ["
                            << state->heart_shift_min * 1e3 << ", " << state->heart_shift_max * 1e3
                            << "] mm");
  }
}

}  // namespace

namespace {

// The phantom a case generates on first use (`phantom:`).
void ReadPhantom(const YamlReader& y, const YAML::Node& root, CaseSpec* spec) {
  CaseSpec& c = *spec;
  if (root["phantom"]) {
    const YAML::Node ph = root["phantom"];
    y.ExpectMap(ph, "phantom",
                {"seed", "body_width", "body_depth", "length", "ribs_per_side", "rib_spacing",
                 "heart_scale", "heart_offset", "voxel_size", "slice_spacing", "field_of_view",
                 "fat_thickness", "wall_thickness", "rib_radius", "rib_drop", "ribs_reach_spine",
                 "shoulders", "table_gap"});
    c.has_phantom = true;
    PhantomParameters& p = c.phantom;
    // Whole numbers in range before the casts (a cast of a negative or huge double is undefined).
    auto whole = [&](const char* key, double fallback, double lo, double hi) {
      const double n = y.NumberOr(ph, key, "phantom", fallback);
      TROCAR_THROW_UNLESS(n == std::floor(n) && n >= lo && n <= hi,
                          y.Where(ph[key], std::string("phantom.") + key)
                              << ": " << n << " (expected a whole number in " << lo << ".." << hi
                              << ")");
      return n;
    };
    p.seed = static_cast<unsigned>(whole("seed", p.seed, 0, 4294967295.0));
    p.body_width = y.NumberOr(ph, "body_width", "phantom", p.body_width);
    p.body_depth = y.NumberOr(ph, "body_depth", "phantom", p.body_depth);
    p.length = y.NumberOr(ph, "length", "phantom", p.length);
    p.ribs_per_side = static_cast<int>(whole("ribs_per_side", p.ribs_per_side, 2, 12));
    p.rib_spacing = y.NumberOr(ph, "rib_spacing", "phantom", p.rib_spacing);
    p.heart_scale = y.NumberOr(ph, "heart_scale", "phantom", p.heart_scale);
    if (ph["heart_offset"]) p.heart_offset = y.Vector3(ph["heart_offset"], "phantom.heart_offset");
    p.voxel_size = y.NumberOr(ph, "voxel_size", "phantom", p.voxel_size);
    p.slice_spacing = y.NumberOr(ph, "slice_spacing", "phantom", p.slice_spacing);
    p.field_of_view = y.NumberOr(ph, "field_of_view", "phantom", p.field_of_view);
    p.fat_thickness = y.NumberOr(ph, "fat_thickness", "phantom", p.fat_thickness);
    p.wall_thickness = y.NumberOr(ph, "wall_thickness", "phantom", p.wall_thickness);
    p.rib_radius = y.NumberOr(ph, "rib_radius", "phantom", p.rib_radius);
    p.rib_drop = y.NumberOr(ph, "rib_drop", "phantom", p.rib_drop);
    if (ph["ribs_reach_spine"]) p.ribs_reach_spine = y.Bool(ph["ribs_reach_spine"], "phantom.ribs_reach_spine");
    if (ph["shoulders"]) p.shoulders = y.Bool(ph["shoulders"], "phantom.shoulders");
    if (ph["table_gap"]) p.table_gap = y.NumberOr(ph, "table_gap", "phantom", p.table_gap);
  }
}

// The CT's units, the segmentation's thresholds, the heart's; soft tissue, blood and bone in
// order.
void ReadThresholds(const YamlReader& y, const YAML::Node& root, CaseSpec* spec) {
  CaseSpec& c = *spec;
  const std::string& case_dir = c.dir;
  if (root["units"]) {
    const std::string u = y.String(root["units"], "units");
    TROCAR_THROW_UNLESS(u == "hounsfield" || u == "raw", y.Where(root["units"], "units")
                                                             << ": '" << u
                                                             << "' (expected hounsfield or raw)");
    c.units = u == "hounsfield" ? 1 : 2;
  }
  if (root["thresholds"]) {
    const YAML::Node t = root["thresholds"];
    y.ExpectMap(t, "thresholds", {"body", "bone", "rib"});
    // In the CT's own units: set both the HU and the raw fields, whichever the CT turns out to be.
    if (t["body"]) c.seg.body_hu = c.seg.raw_body = y.Number(t["body"], "thresholds.body");
    if (t["bone"]) c.seg.bone_hu = c.seg.raw_bone = y.Number(t["bone"], "thresholds.bone");
    c.thresholds_given = t["body"] || t["bone"];
    TROCAR_THROW_UNLESS(c.seg.body_hu < c.seg.bone_hu && c.seg.raw_body < c.seg.raw_bone,
                        y.Where(t, "thresholds")
                            << ": the body threshold must be below the bone threshold");
    // A windowed volume's rib floor (the chart of the rib cage's layer); measured when not given.
    if (t["rib"]) {
      c.intercostal.layer_floor = y.Number(t["rib"], "thresholds.rib");
      TROCAR_THROW_UNLESS(
          c.intercostal.layer_floor > c.seg.raw_body && c.intercostal.layer_floor < c.seg.raw_bone,
          y.Where(t["rib"], "thresholds.rib")
              << ": " << c.intercostal.layer_floor << " must lie between the body threshold ("
              << c.seg.raw_body << ") and the bone threshold (" << c.seg.raw_bone << ")");
    }
  }
  if (root["bones"]) {
    // How bone is sorted into ribs, sternum and spine: by shape and place (the default), or by
    // place in the body's bounding box alone (the earlier rule, kept for comparison).
    const std::string b = y.String(root["bones"], "bones");
    TROCAR_THROW_UNLESS(b == "shape" || b == "place", y.Where(root["bones"], "bones")
                                                          << ": '" << b << "' (expected shape or place)");
    c.seg.shape_anatomy = b == "shape";
  }
  if (root["vessels"]) {
    // Bone-bright blobs a ball of this radius fits in, off the spine's column, are
    // contrast-filled vessels and heart chambers, not bone (AnatomyOptions::vessel_core_radius);
    // given, it is not chosen from how the ribs read.
    const YAML::Node v = root["vessels"];
    y.ExpectMap(v, "vessels", {"core_radius"});
    if (v["core_radius"]) {
      const double r = y.Number(v["core_radius"], "vessels.core_radius");
      TROCAR_THROW_UNLESS(r >= 0.001 && r <= 0.02, y.Where(v["core_radius"], "vessels.core_radius")
                                                       << ": " << r
                                                       << " m (expected 0.001-0.02 m)");
      c.seg.anatomy.vessel_core_radius = c.seg.anatomy.raw_vessel_core_radius = r;
      c.seg.anatomy.raw_cortex_core_radius = 0.0;  // as given, not chosen from the ribs
    }
  }
  if (root["heart"]) {
    const YAML::Node h = root["heart"];
    y.ExpectMap(h, "heart", {"mask", "threshold", "contrast", "blood", "soft", "opening_radius"});
    if (h["mask"]) {
      c.heart_mask = JoinPath(case_dir, y.String(h["mask"], "heart.mask"));
      TROCAR_THROW_UNLESS(IsRegularFile(c.heart_mask), y.Where(h["mask"], "heart.mask")
                                                           << ": file " << c.heart_mask
                                                           << " not found");
      c.heart_mask_threshold = y.NumberOr(h, "threshold", "heart", 0.5);
    }
    if (h["contrast"]) c.heart_contrast = y.Bool(h["contrast"], "heart.contrast");
    if (h["blood"]) c.heart.blood_hu = c.heart.raw_blood = y.Number(h["blood"], "heart.blood");
    if (h["soft"]) c.heart.soft_hu = c.heart.raw_soft = y.Number(h["soft"], "heart.soft");
    c.heart.opening_radius = y.NumberOr(h, "opening_radius", "heart", c.heart.opening_radius);
    TROCAR_THROW_UNLESS(c.heart.opening_radius > 0.0 && c.heart.opening_radius <= 0.05,
                        y.Where(h, "heart.opening_radius")
                            << ": " << c.heart.opening_radius << " m (expected 0-0.05 m)");
  }
  // Thresholds in order, in whichever units the CT turns out to have: soft tissue < blood <
  // bone. Out of order they make most of the body "heart" or "bone" (a 21-litre heart).
  for (const auto& [units, soft, blood, bone] :
       {std::make_tuple("Hounsfield", c.heart.soft_hu, c.heart.blood_hu, c.seg.bone_hu),
        std::make_tuple("raw", c.heart.raw_soft, c.heart.raw_blood, c.seg.raw_bone)}) {
    TROCAR_THROW_UNLESS(soft < blood && blood < bone,
                        c.file << ": thresholds out of order (" << units << " units): heart.soft "
                               << soft << ", heart.blood " << blood << ", thresholds.bone " << bone
                               << " (expected soft < blood < bone)");
  }
}

// The label map, the orientation check, the pose, the operation, the table.
void ReadLabelsAndPose(const YamlReader& y, const YAML::Node& root, CaseSpec* spec) {
  CaseSpec& c = *spec;
  const std::string& case_dir = c.dir;
  if (root["labels"]) {
    // A label map: `labels: seg.nii.gz`, or `labels: {file: seg.nii.gz, names: seg.json}`.
    const YAML::Node l = root["labels"];
    if (l.IsMap()) {
      y.ExpectMap(l, "labels", {"file", "names"});
      c.labels = JoinPath(case_dir, y.String(y.Require(l, "file", "labels"), "labels.file"));
      if (l["names"]) {
        c.label_names = JoinPath(case_dir, y.String(l["names"], "labels.names"));
        TROCAR_THROW_UNLESS(IsRegularFile(c.label_names), y.Where(l["names"], "labels.names")
                                                              << ": file " << c.label_names << " not found");
      }
    } else {
      c.labels = JoinPath(case_dir, y.String(l, "labels"));
    }
    TROCAR_THROW_UNLESS(std::filesystem::exists(c.labels),
                        y.Where(l, "labels") << ": " << c.labels << " not found (a label map file or a folder of masks)");
  }
  if (root["orientation"]) {
    const YAML::Node o = root["orientation"];
    y.ExpectMap(o, "orientation", {"check"});
    if (o["check"]) c.check_orientation = y.Bool(o["check"], "orientation.check");
  }
  if (root["pose"]) {
    const YAML::Node p = root["pose"];
    y.ExpectMap(p, "pose", {"left_side_up"});
    c.left_side_up = y.NumberOr(p, "left_side_up", "pose", 0.0);
    TROCAR_THROW_UNLESS(c.left_side_up >= -M_PI / 4 && c.left_side_up <= M_PI / 4,
                        y.Where(p["left_side_up"], "pose.left_side_up")
                            << ": " << c.left_side_up * 180 / M_PI
                            << " deg is outside -45..45 deg (write e.g. '25 deg')");
  }
  if (root["operation"]) ReadOperation(y, root["operation"], &c.operation);
  if (root["table"]) {
    const YAML::Node t = root["table"];
    y.ExpectMap(t, "table", {"height", "width", "length"});
    c.table.height = y.NumberOr(t, "height", "table", c.table.height);
    c.table.width = y.NumberOr(t, "width", "table", c.table.width);
    c.table.length = y.NumberOr(t, "length", "table", c.table.length);
    TROCAR_THROW_UNLESS(
        c.table.height > 0.3 && c.table.height < 1.5 && c.table.width > 0.2 &&
            c.table.width < 2.0 && c.table.length > 0.5 && c.table.length < 4.0,
        y.Where(t, "table") << ": table height 0.3-1.5 m, width 0.2-2 m, length 0.5-4 m expected");
  }
}

// The targets and the port candidates (annotated curves, or the intercostal spaces to find).
void ReadTargetsAndPorts(const YamlReader& y, const YAML::Node& root, CaseSpec* spec) {
  CaseSpec& c = *spec;
  const std::string& case_dir = c.dir;
  if (root["targets"]) {
    y.ExpectSequence(root["targets"], "targets");
    for (std::size_t i = 0; i < root["targets"].size(); ++i) {
      const YAML::Node t = root["targets"][i];
      const std::string path = "targets[" + std::to_string(i) + "]";
      y.ExpectMap(t, path, {"name", "markups", "surface", "facing", "normals"});
      TargetSpec s;
      s.name = y.String(y.Require(t, "name", path), path + ".name");
      s.markups = JoinPath(case_dir, y.String(y.Require(t, "markups", path), path + ".markups"));
      // A phantom case generates its markups with its CT on first use.
      const bool generated = c.has_phantom && !std::filesystem::exists(c.ct);
      TROCAR_THROW_UNLESS(generated || IsRegularFile(s.markups),
                          y.Where(t["markups"], path + ".markups")
                              << ": file " << s.markups << " not found");
      if (t["surface"]) {
        s.surface = y.String(t["surface"], path + ".surface");
        TROCAR_THROW_UNLESS(
            s.surface == "skin" || s.surface == "ribs" || s.surface == "sternum" ||
                s.surface == "spine" || s.surface == "heart",
            y.Where(t["surface"], path + ".surface")
                << ": surface '" << s.surface
                << "' is not a structure of the model (skin, ribs, sternum, spine, heart)");
      }
      if (t["facing"]) {
        const std::string f = y.String(t["facing"], path + ".facing");
        TROCAR_THROW_UNLESS(f == "outward" || f == "inward",
                            y.Where(t["facing"], path + ".facing")
                                << ": '" << f << "' (expected outward or inward)");
        s.inward = f == "inward";
      }
      if (t["normals"]) {
        s.normals = y.String(t["normals"], path + ".normals");
        TROCAR_THROW_UNLESS(s.normals == "auto" || s.normals == "file" || s.normals == "surface",
                            y.Where(t["normals"], path + ".normals")
                                << ": '" << s.normals << "' (expected auto, file or surface)");
      }
      c.targets.push_back(s);
    }
  }
  if (root["port_candidates"]) {
    const YAML::Node pc = root["port_candidates"];
    const std::vector<std::string> files =
        pc.IsSequence() ? y.Strings(pc, "port_candidates")
                        : std::vector<std::string>{y.String(pc, "port_candidates")};
    for (const auto& f : files) {
      const std::string p = JoinPath(case_dir, f);
      TROCAR_THROW_UNLESS((c.has_phantom && !std::filesystem::exists(c.ct)) || IsRegularFile(p),
                          y.Where(pc, "port_candidates") << ": file " << p << " not found");
      c.port_markups.push_back(p);
    }
  }
  if (root["intercostal"]) {
    const YAML::Node ic = root["intercostal"];
    y.ExpectMap(ic, "intercostal", {"left", "right", "count_from"});
    if (ic["left"]) c.intercostal.left = y.Bool(ic["left"], "intercostal.left");
    if (ic["right"]) c.intercostal.right = y.Bool(ic["right"], "intercostal.right");
    if (ic["count_from"]) {
      // The user's count of spaces whose ribs the import cannot number (no rib 1 in view).
      const double n = y.Number(ic["count_from"], "intercostal.count_from");
      TROCAR_THROW_UNLESS(n == std::floor(n) && n >= 1 && n <= 11,
                          y.Where(ic["count_from"], "intercostal.count_from")
                              << ": " << n
                              << " is not an intercostal space's number (expected a whole number "
                                 "1 to 11: the number of the highest space found)");
      c.intercostal.count_from = static_cast<int>(n);
    }
  }
}

// The surfaces' triangle budgets and smoothing.
void ReadSurfaces(const YamlReader& y, const YAML::Node& root, CaseSpec* spec) {
  CaseSpec& c = *spec;
  if (root["surfaces"]) {
    const YAML::Node s = root["surfaces"];
    y.ExpectMap(s, "surfaces", {"skin", "ribs", "sternum", "spine", "heart", "vessels", "smoothing"});
    auto budget = [&](const char* key, int* v) {
      if (!s[key]) return;
      const double n = y.Number(s[key], std::string("surfaces.") + key);
      TROCAR_THROW_UNLESS(n >= 100 && n <= 5e6, y.Where(s[key], std::string("surfaces.") + key)
                                                    << ": triangle budget " << n
                                                    << " outside 100..5000000");
      *v = static_cast<int>(n);
    };
    budget("skin", &c.budgets.skin);
    budget("ribs", &c.budgets.ribs);
    budget("sternum", &c.budgets.sternum);
    budget("spine", &c.budgets.spine);
    budget("heart", &c.budgets.heart);
    budget("vessels", &c.budgets.vessels);
    if (s["smoothing"]) {
      const double n = y.Number(s["smoothing"], "surfaces.smoothing");
      TROCAR_THROW_UNLESS(n == std::floor(n) && n >= 0 && n <= 500,
                          y.Where(s["smoothing"], "surfaces.smoothing")
                              << ": " << n << " (expected a whole number of iterations, 0..500)");
      c.surface.smoothing_iterations = static_cast<int>(n);
    }
  }
}

}  // namespace

CaseSpec ReadCase(const std::string& case_dir) {
  CaseSpec c;
  c.dir = case_dir;
  c.file = JoinPath(case_dir, "patient.yaml");
  TROCAR_THROW_UNLESS(IsRegularFile(c.file),
                      case_dir << ": no patient.yaml (a case folder holds patient.yaml, see "
                                  "patients/README.md)");
  const YamlReader y = YamlReader::Load(c.file);
  const YAML::Node& root = y.root();
  y.ExpectMap(root, "patient.yaml",
              {"name", "ct", "phantom", "units", "thresholds", "heart", "pose", "table", "targets",
               "port_candidates", "intercostal", "surfaces", "plan", "labels", "orientation",
               "bones", "vessels", "operation"});  // plan: read by trocar plan
  c.name = root["name"] ? y.String(root["name"], "name")
                        : std::filesystem::path(case_dir).filename().string();
  c.ct = JoinPath(case_dir, y.String(y.Require(root, "ct", ""), "ct"));
  ReadPhantom(y, root, &c);
  ReadThresholds(y, root, &c);
  ReadLabelsAndPose(y, root, &c);
  ReadTargetsAndPorts(y, root, &c);
  ReadSurfaces(y, root, &c);
  return c;
}

}  // namespace trocar::patient
