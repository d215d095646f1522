#include "patient/patient_model.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <functional>
#include <iomanip>
#include <sstream>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/yaml_util.hpp"
#include "patient/intercostal.hpp"
#include "patient/label_map.hpp"
#include "patient/markups.hpp"
#include "patient/sanity.hpp"
#include "patient/segmentation.hpp"
#include "patient/surface.hpp"

namespace trocar::patient {

const Structure* PatientModel::Find(const std::string& wanted) const {
  for (const auto& s : structures) {
    if (s.name == wanted) return &s;
  }
  return nullptr;
}

long PatientModel::triangle_count() const {
  long n = 0;
  for (const auto& s : structures) n += static_cast<long>(s.mesh.triangles.size());
  return n;
}

Eigen::Vector3d NearestSurfaceNormal(const TriangleMesh& mesh, const Eigen::Vector3d& p_P) {
  TROCAR_THROW_UNLESS(!mesh.vertices.empty(), mesh.source << ": no vertices for a normal");
  std::size_t best = 0;
  double best_d = HUGE_VAL;
  for (std::size_t v = 0; v < mesh.vertices.size(); ++v) {
    const double d = (mesh.vertices[v] - p_P).squaredNorm();
    if (d < best_d) {
      best_d = d;
      best = v;
    }
  }
  Eigen::Vector3d n = Eigen::Vector3d::Zero();
  for (const auto& t : mesh.triangles) {
    if (t[0] != int(best) && t[1] != int(best) && t[2] != int(best)) continue;
    n += (mesh.vertices[t[1]] - mesh.vertices[t[0]])
             .cross(mesh.vertices[t[2]] - mesh.vertices[t[0]]);
  }
  TROCAR_THROW_UNLESS(n.norm() > 0.0, mesh.source << ": vertex " << best << " has no triangles");
  return n.normalized();
}

Eigen::Isometry3d PoseOnTable(const TriangleMesh& skin, double left_side_up, const Table& table) {
  // Supine, head toward +x_W: superior z_P = x_W, posterior y_P = -z_W, left x_P = -y_W; then
  // the left side is raised by rotating about the body axis.
  Eigen::Matrix3d R0;
  R0.col(0) = -Eigen::Vector3d::UnitY();
  R0.col(1) = -Eigen::Vector3d::UnitZ();
  R0.col(2) = Eigen::Vector3d::UnitX();
  const Eigen::Matrix3d R_WP = Eigen::AngleAxisd(-left_side_up, Eigen::Vector3d::UnitX()) * R0;
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(HUGE_VAL), hi = -lo;
  for (const auto& v : skin.vertices) {
    const Eigen::Vector3d w = R_WP * v;
    lo = lo.cwiseMin(w);
    hi = hi.cwiseMax(w);
  }
  Eigen::Isometry3d X_WP = Eigen::Isometry3d::Identity();
  X_WP.linear() = R_WP;
  X_WP.translation() =
      Eigen::Vector3d(-0.5 * (lo.x() + hi.x()), -0.5 * (lo.y() + hi.y()), table.height - lo.z());
  return X_WP;
}

// ---------------------------------------------------------------- serialisation
namespace {

constexpr char kMagic[8] = {'T', 'R', 'O', 'C', 'P', 'M', '0', '2'};

struct Writer {
  std::string out;
  template <typename T>
  void Pod(const T& v) {
    out.append(reinterpret_cast<const char*>(&v), sizeof(T));
  }
  void Str(const std::string& s) {
    Pod<std::uint64_t>(s.size());
    out += s;
  }
  void Vec(const Eigen::Vector3d& v) {
    for (int i = 0; i < 3; ++i) Pod(v[i]);
  }
  void Vecs(const std::vector<Eigen::Vector3d>& vs) {
    Pod<std::uint64_t>(vs.size());
    for (const auto& v : vs) Vec(v);
  }
};

struct Reader {
  const std::string& in;
  std::size_t pos = 0;
  bool ok = true;
  template <typename T>
  T Pod() {
    T v{};
    if (pos + sizeof(T) > in.size()) {
      ok = false;
      return v;
    }
    std::memcpy(&v, in.data() + pos, sizeof(T));
    pos += sizeof(T);
    return v;
  }
  std::uint64_t Count(std::size_t item_bytes) {
    const auto n = Pod<std::uint64_t>();
    if (!ok || n > (in.size() - pos) / std::max<std::size_t>(item_bytes, 1)) {
      ok = false;
      return 0;
    }
    return n;
  }
  std::string Str() {
    const auto n = Count(1);
    if (!ok) return {};
    std::string s = in.substr(pos, n);
    pos += n;
    return s;
  }
  Eigen::Vector3d Vec() {
    Eigen::Vector3d v;
    for (int i = 0; i < 3; ++i) v[i] = Pod<double>();
    return v;
  }
  std::vector<Eigen::Vector3d> Vecs() {
    std::vector<Eigen::Vector3d> vs(Count(24));
    for (auto& v : vs) v = Vec();
    return vs;
  }
};

}  // namespace

std::string SerializeModel(const PatientModel& m, std::uint64_t key) {
  Writer w;
  w.out.append(kMagic, 8);
  w.Pod(key);
  w.Str(m.name);
  w.Str(m.ct_source);
  w.Pod<std::uint64_t>(m.structures.size());
  for (const auto& s : m.structures) {
    w.Str(s.name);
    w.Pod(s.volume);
    w.Pod<std::int64_t>(s.contoured_triangles);
    w.Vecs(s.mesh.vertices);
    w.Pod<std::uint64_t>(s.mesh.triangles.size());
    for (const auto& t : s.mesh.triangles) {
      for (int i = 0; i < 3; ++i) w.Pod<std::int32_t>(t[i]);
    }
  }
  w.Pod<std::uint64_t>(m.targets.size());
  for (const auto& t : m.targets) {
    w.Str(t.name);
    w.Str(t.normals_from);
    w.Vecs(t.points);
    w.Vecs(t.normals);
  }
  w.Pod<std::uint64_t>(m.port_candidates.size());
  for (const auto& c : m.port_candidates) {
    w.Str(c.name);
    w.Str(c.source);
    w.Vecs(c.skin);
  }
  w.Pod(m.table.height);
  w.Pod(m.table.width);
  w.Pod(m.table.length);
  w.Pod(m.table.thickness);
  w.Pod(m.left_side_up);
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) w.Pod(m.X_WP.matrix()(r, c));
  }
  w.Vec(m.body_min_P);
  w.Vec(m.body_max_P);
  for (const auto* lines : {&m.checks, &m.warnings, &m.cut_faces}) {
    w.Pod<std::uint64_t>(lines->size());
    for (const auto& line : *lines) w.Str(line);
  }
  w.out.append(kMagic, 8);  // trailer: a truncated file never loads
  return w.out;
}

bool DeserializeModel(const std::string& bytes, std::uint64_t key, PatientModel* out) {
  if (bytes.size() < 24 || std::memcmp(bytes.data(), kMagic, 8) != 0 ||
      std::memcmp(bytes.data() + bytes.size() - 8, kMagic, 8) != 0) {
    return false;
  }
  Reader r{bytes, 8};
  if (r.Pod<std::uint64_t>() != key) return false;
  PatientModel m;
  m.name = r.Str();
  m.ct_source = r.Str();
  m.structures.resize(r.Count(40));
  for (auto& s : m.structures) {
    s.name = r.Str();
    s.mesh.source = s.name;
    s.volume = r.Pod<double>();
    s.contoured_triangles = r.Pod<std::int64_t>();
    s.mesh.vertices = r.Vecs();
    s.mesh.triangles.resize(r.Count(12));
    for (auto& t : s.mesh.triangles) {
      for (int i = 0; i < 3; ++i) t[i] = r.Pod<std::int32_t>();
      if ((t.array() < 0).any() || (t.array() >= int(s.mesh.vertices.size())).any()) r.ok = false;
    }
  }
  m.targets.resize(r.Count(32));
  for (auto& t : m.targets) {
    t.name = r.Str();
    t.normals_from = r.Str();
    t.points = r.Vecs();
    t.normals = r.Vecs();
  }
  m.port_candidates.resize(r.Count(24));
  for (auto& c : m.port_candidates) {
    c.name = r.Str();
    c.source = r.Str();
    c.skin = r.Vecs();
  }
  m.table.height = r.Pod<double>();
  m.table.width = r.Pod<double>();
  m.table.length = r.Pod<double>();
  m.table.thickness = r.Pod<double>();
  m.left_side_up = r.Pod<double>();
  for (int row = 0; row < 4; ++row) {
    for (int c = 0; c < 4; ++c) m.X_WP.matrix()(row, c) = r.Pod<double>();
  }
  m.body_min_P = r.Vec();
  m.body_max_P = r.Vec();
  for (auto* lines : {&m.checks, &m.warnings, &m.cut_faces}) {
    lines->resize(r.Count(8));
    for (auto& line : *lines) line = r.Str();
  }
  if (!r.ok || r.pos + 8 != bytes.size()) return false;
  *out = std::move(m);
  return true;
}

// ---------------------------------------------------------------- the case file
namespace {

std::uint64_t Fnv1a(std::uint64_t h, const std::string& bytes) {
  for (unsigned char c : bytes) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

struct Budgets {
  int skin = 30000, ribs = 40000, sternum = 4000, spine = 12000, heart = 15000, vessels = 8000;
};

// The coarsest grid a structure is contoured on (m): thin bone keeps 2 mm, the skin and the heart
// are smooth and large (their triangles, at the budgets above, are 5-8 mm across anyway).
double MaxWorkingSpacing(const std::string& structure) {
  if (structure == "skin") return 0.006;
  if (structure == "heart") return 0.004;
  if (structure == "spine") return 0.003;
  return 0.002;
}

struct TargetSpec {
  std::string name, markups, surface = "heart";
  bool inward = false;
  std::string normals = "auto";  // auto: the file's orientations when present, else surface
};

struct CaseSpec {
  std::string file, dir, name, ct;
  bool has_phantom = false;
  PhantomParameters phantom;
  int units = 0;  // 0 auto, 1 hounsfield, 2 raw
  SegmentationOptions seg;
  std::string heart_mask;
  double heart_mask_threshold = 0.5;
  std::string labels, label_names;  // a label map (file or folder of masks) and its names' sidecar
  bool heart_contrast = true;
  bool check_orientation = true;
  HeartOptions heart;
  double left_side_up = 0.0;
  Table table;
  std::vector<TargetSpec> targets;
  std::vector<std::string> port_markups;
  IntercostalOptions intercostal;
  Budgets budgets;
  SurfaceOptions surface;
};

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
               "port_candidates", "intercostal", "surfaces", "plan", "labels", "orientation"});  // plan: read by trocar plan
  c.name = root["name"] ? y.String(root["name"], "name")
                        : std::filesystem::path(case_dir).filename().string();
  c.ct = JoinPath(case_dir, y.String(y.Require(root, "ct", ""), "ct"));
  if (root["phantom"]) {
    const YAML::Node ph = root["phantom"];
    y.ExpectMap(ph, "phantom",
                {"seed", "body_width", "body_depth", "length", "ribs_per_side", "rib_spacing",
                 "heart_scale", "heart_offset", "voxel_size", "slice_spacing", "field_of_view"});
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
  }
  if (root["units"]) {
    const std::string u = y.String(root["units"], "units");
    TROCAR_THROW_UNLESS(u == "hounsfield" || u == "raw", y.Where(root["units"], "units")
                                                             << ": '" << u
                                                             << "' (expected hounsfield or raw)");
    c.units = u == "hounsfield" ? 1 : 2;
  }
  if (root["thresholds"]) {
    const YAML::Node t = root["thresholds"];
    y.ExpectMap(t, "thresholds", {"body", "bone"});
    // In the CT's own units: set both the HU and the raw fields, whichever the CT turns out to be.
    if (t["body"]) c.seg.body_hu = c.seg.raw_body = y.Number(t["body"], "thresholds.body");
    if (t["bone"]) c.seg.bone_hu = c.seg.raw_bone = y.Number(t["bone"], "thresholds.bone");
    TROCAR_THROW_UNLESS(c.seg.body_hu < c.seg.bone_hu && c.seg.raw_body < c.seg.raw_bone,
                        y.Where(t, "thresholds")
                            << ": the body threshold must be below the bone threshold");
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
  }
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
  if (root["table"]) {
    const YAML::Node t = root["table"];
    y.ExpectMap(t, "table", {"height", "width", "length"});
    c.table.height = y.NumberOr(t, "height", "table", c.table.height);
    c.table.width = y.NumberOr(t, "width", "table", c.table.width);
    c.table.length = y.NumberOr(t, "length", "table", c.table.length);
    TROCAR_THROW_UNLESS(
        c.table.height > 0.3 && c.table.height < 1.5 && c.table.width > 0.2 && c.table.length > 0.5,
        y.Where(t, "table") << ": table height 0.3-1.5 m, width > 0.2 m, length > 0.5 m expected");
  }
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
    y.ExpectMap(ic, "intercostal", {"left", "right"});
    if (ic["left"]) c.intercostal.left = y.Bool(ic["left"], "intercostal.left");
    if (ic["right"]) c.intercostal.right = y.Bool(ic["right"], "intercostal.right");
  }
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
  return c;
}

// The files of a folder (a DICOM series', a label map's), sorted.
std::vector<std::string> FolderFiles(const std::string& dir) {
  std::vector<std::string> files;
  std::error_code ec;
  for (std::filesystem::directory_iterator it(dir, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->is_regular_file(ec)) files.push_back(it->path().string());
  }
  TROCAR_THROW_UNLESS(!ec, dir << ": cannot list the folder: " << ec.message());
  std::sort(files.begin(), files.end());
  return files;
}

// Every file the model depends on, for the cache key: the case file, the CT's files (`ct_files`:
// what the CT reader read, a detached data file or a series' slices too), masks, label maps and
// markups. A CT folder's whole listing counts as well (a slice added to it changes the key).
std::vector<std::string> InputFiles(const CaseSpec& c, const std::vector<std::string>& ct_files) {
  std::vector<std::string> files = {c.file};
  files.insert(files.end(), ct_files.begin(), ct_files.end());
  if (std::filesystem::is_directory(c.ct)) {
    const auto listing = FolderFiles(c.ct);
    files.insert(files.end(), listing.begin(), listing.end());
  }
  if (!c.heart_mask.empty()) files.push_back(c.heart_mask);
  if (!c.labels.empty()) {
    if (std::filesystem::is_directory(c.labels)) {
      const auto masks = FolderFiles(c.labels);
      files.insert(files.end(), masks.begin(), masks.end());
    } else {
      files.push_back(c.labels);
      if (!c.label_names.empty()) files.push_back(c.label_names);
    }
  }
  for (const auto& t : c.targets) files.push_back(t.markups);
  files.insert(files.end(), c.port_markups.begin(), c.port_markups.end());
  return files;
}

std::uint64_t CacheKey(const std::vector<std::string>& files) {
  std::uint64_t h = Fnv1a(14695981039346656037ull, "trocar patient model v3");
  for (const auto& f : files) {
    h = Fnv1a(h, std::filesystem::path(f).filename().string());
    h = Fnv1a(h, ReadTextFile(f));
  }
  return h;
}

// cache/ct_files.txt: the CT's files as the last build read them (absolute paths), so that a
// cached load keys the model without decoding the CT. Empty when absent, damaged or naming a file
// that is gone (the caller then reads the CT).
constexpr char kCtFilesHeader[] = "trocar ct files v1";

std::vector<std::string> ReadCtFiles(const std::string& cache_dir) {
  const std::string path = JoinPath(cache_dir, "ct_files.txt");
  if (!IsRegularFile(path)) return {};
  std::istringstream in(ReadTextFile(path));
  std::string line;
  if (!std::getline(in, line) || line != kCtFilesHeader) return {};
  std::vector<std::string> files;
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    if (!IsRegularFile(line)) return {};
    files.push_back(line);
  }
  return files;
}

std::string CtFilesText(const std::vector<std::string>& files) {
  std::string text = std::string(kCtFilesHeader) + "\n";
  for (const auto& f : files) text += std::filesystem::absolute(f).lexically_normal().string() + "\n";
  return text;
}

Mask LabelMask(const Volume& ct, const std::vector<int>& labels,
               const std::vector<const std::vector<Component>*>& groups) {
  std::vector<std::uint8_t> wanted;
  for (const auto* g : groups) {
    for (const auto& comp : *g) {
      if (comp.label >= int(wanted.size())) wanted.resize(comp.label + 1, 0);
      wanted[comp.label] = 1;
    }
  }
  Mask m;
  m.size = ct.size;
  m.inside.assign(ct.values.size(), 0);
  for (std::size_t n = 0; n < labels.size(); ++n) {
    m.inside[n] = labels[n] > 0 && labels[n] < int(wanted.size()) && wanted[labels[n]];
  }
  return m;
}

void WriteCacheFiles(const PatientModel& m, const std::string& cache_dir, std::uint64_t key,
                     const std::vector<std::string>& ct_files) {
  std::error_code ec;
  std::filesystem::create_directories(cache_dir, ec);
  TROCAR_THROW_UNLESS(!ec, cache_dir << ": cannot create the cache folder: " << ec.message());
  for (const auto& s : m.structures) WriteStl(s.mesh, JoinPath(cache_dir, s.name + ".stl"));
  std::vector<Markup> targets, ports;
  for (const auto& t : m.targets) {
    Markup mk;
    mk.name = t.name;
    mk.type = "Curve";
    mk.points = t.points;
    mk.normals = t.normals;
    targets.push_back(mk);
  }
  for (const auto& c : m.port_candidates) {
    Markup mk;
    mk.name = c.name;
    mk.type = "Curve";
    mk.points = c.skin;
    ports.push_back(mk);
  }
  if (!targets.empty()) WriteMarkups(targets, JoinPath(cache_dir, "targets.mrk.json"));
  if (!ports.empty()) WriteMarkups(ports, JoinPath(cache_dir, "port_candidates.mrk.json"));
  WriteFileAtomically(JoinPath(cache_dir, "ct_files.txt"), CtFilesText(ct_files));
  // model.bin last: its presence with a matching key means the whole cache is written.
  WriteFileAtomically(JoinPath(cache_dir, "model.bin"), SerializeModel(m, key));
}

}  // namespace

PatientModel ImportPatient(const std::string& case_dir, const ImportOptions& options) {
  using Clock = std::chrono::steady_clock;
  std::vector<std::pair<std::string, double>> timings;
  auto stage = [&](const std::string& name, const std::function<void()>& f) {
    const auto t0 = Clock::now();
    f();
    timings.emplace_back(name, std::chrono::duration<double>(Clock::now() - t0).count());
  };
  CaseSpec c = ReadCase(case_dir);
  if (c.has_phantom && !std::filesystem::exists(c.ct)) {
    stage("generate phantom", [&] {
      WritePhantomCase(GeneratePhantom(c.phantom), case_dir, CtFormat::kNrrdLps,
                       /*write_patient_yaml=*/false);
    });
  }
  const std::string cache_dir = JoinPath(case_dir, "cache");
  const std::string model_bin = JoinPath(cache_dir, "model.bin");
  auto load_cache = [&](std::uint64_t key, PatientModel* cached) {
    const auto t0 = Clock::now();
    if (!DeserializeModel(ReadTextFile(model_bin), key, cached)) return false;
    cached->case_dir = case_dir;
    cached->from_cache = true;
    cached->timings = timings;
    cached->timings.emplace_back("load cache", std::chrono::duration<double>(Clock::now() - t0).count());
    return true;
  };
  const bool cache_exists = options.use_cache && IsRegularFile(model_bin);
  if (cache_exists) {
    // Keyed by the CT files the last build read, without decoding the CT (a clinical CT takes a
    // second to decode; the whole cached load must take less).
    const std::vector<std::string> last_ct_files = ReadCtFiles(cache_dir);
    PatientModel cached;
    if (!last_ct_files.empty()) {
      std::uint64_t key = 0;
      stage("key inputs", [&] { key = CacheKey(InputFiles(c, last_ct_files)); });
      if (load_cache(key, &cached)) return cached;
    }
  }
  Volume ct;
  stage("load CT", [&] { ct = LoadVolume(c.ct); });
  const std::uint64_t key = CacheKey(InputFiles(c, ct.files));
  if (cache_exists) {
    PatientModel cached;
    if (load_cache(key, &cached)) return cached;
  }
  if (c.units == 1) ct.hounsfield = true;
  if (c.units == 2) ct.hounsfield = false;

  PatientModel m;
  m.name = c.name;
  m.case_dir = case_dir;
  m.ct_source = c.ct;
  m.table = c.table;
  m.left_side_up = c.left_side_up;
  Segmentation seg;
  stage("segment body and bone", [&] { seg = Segment(ct, c.seg); });
  LabelledAnatomy labelled;
  const bool have_labels = !c.labels.empty();
  if (have_labels) {
    // Bones, heart and vessels from the label map; the body (skin) stays the CT's own.
    stage("label map", [&] {
      labelled = AnatomyFromLabels(LoadLabelMap(c.labels, c.label_names), ct);
      seg.bones = labelled.bones;
    });
  }
  m.body_min_P = seg.body_min_P;
  m.body_max_P = seg.body_max_P;
  Mask heart;
  bool have_heart = false;
  stage("heart", [&] {
    if (!c.heart_mask.empty()) {
      heart = ResampleMask(LoadVolume(c.heart_mask), ct, c.heart_mask_threshold);
      TROCAR_THROW_UNLESS(heart.count() > 0, c.heart_mask << ": the heart mask is empty on the CT");
      have_heart = true;
    } else if (have_labels && labelled.heart.count() > 0) {
      heart = labelled.heart;
      have_heart = true;
    } else if (c.heart_contrast) {
      heart = SegmentHeartFromContrast(ct, seg, c.heart);
      have_heart = true;
    }
  });
  stage("checks", [&] {
    // Orientation from anatomy: a flipped or mirrored header is an error (or, with
    // orientation: {check: false}, a warning), never a silent import.
    const OrientationCheck o = CheckOrientation(ct, seg, have_heart ? &heart : nullptr);
    for (const auto& f : o.findings) m.checks.push_back("orientation: " + f);
    if (o.flipped()) {
      std::ostringstream what;
      what << c.ct << ": the anatomy disagrees with the header's orientation:";
      for (const auto& f : o.findings) what << "\n  " << f;
      what << "\n(fix the header, e.g. re-export the CT from the scanner's DICOM; or, for a "
              "patient whose anatomy is mirrored, set orientation: {check: false} in "
           << c.file << ")";
      TROCAR_THROW_UNLESS(!c.check_orientation, what.str());
      m.warnings.push_back("orientation: the anatomy disagrees with the header (not checked, "
                           "orientation.check is false)");
    }
    for (const CutFace& f : FindCutFaces(ct, seg.body)) {
      m.cut_faces.push_back(f.name);
      if (f.name != "superior" && f.name != "inferior") {
        std::ostringstream s;
        s << "the body is cut by the scan's " << f.name << " face (" << std::setprecision(2) << 100 * f.body_fraction
          << "% of it): the skin there is a crop face; no port candidate within "
          << PatientModel::kCutFaceMargin * 1e3 << " mm of it";
        m.warnings.push_back(s.str());
      }
    }
    if (!m.cut_faces.empty()) {
      std::string names;
      for (const auto& n : m.cut_faces) names += (names.empty() ? "" : ", ") + n;
      m.checks.push_back("cut faces: " + names);
    }
  });
  if (!have_heart) {
    m.warnings.push_back("no heart in the model (heart.contrast is false and there is no heart "
                         "mask or label): plans will not avoid it");
  }
  const double voxel = std::abs(ct.index_to_P.determinant());
  auto add = [&](const std::string& name, const Mask& mask, int budget) {
    if (mask.count() == 0) return;
    SurfaceOptions o = c.surface;
    o.max_triangles = budget;
    o.max_working_spacing = MaxWorkingSpacing(name);
    SurfaceReport report;
    Structure s;
    s.name = name;
    s.mesh = ExtractSurface(ct, mask, name, o, &report);
    s.volume = mask.count() * voxel;
    s.contoured_triangles = report.contoured_triangles;
    m.structures.push_back(std::move(s));
  };
  stage("surfaces", [&] {
    add("skin", seg.body, c.budgets.skin);
    add("ribs", LabelMask(ct, seg.bones.labels, {&seg.bones.ribs_left, &seg.bones.ribs_right}),
        c.budgets.ribs);
    add("sternum", LabelMask(ct, seg.bones.labels, {&seg.bones.sternum}), c.budgets.sternum);
    add("spine", LabelMask(ct, seg.bones.labels, {&seg.bones.spine}), c.budgets.spine);
    if (have_heart) add("heart", heart, c.budgets.heart);
    if (have_labels) add("vessels", labelled.vessels, c.budgets.vessels);
  });
  stage("targets", [&] {
    for (const auto& spec : c.targets) {
      const auto markups = LoadMarkups(spec.markups);
      Target t;
      t.name = spec.name;
      for (const auto& mk : markups) {
        t.points.insert(t.points.end(), mk.points.begin(), mk.points.end());
        t.normals.insert(t.normals.end(), mk.normals.begin(), mk.normals.end());
      }
      TROCAR_THROW_UNLESS(!t.points.empty(), spec.markups << ": target '" << spec.name << "' has no points");
      // Every target point inside the scanned box: beyond it the model knows nothing.
      {
        const Eigen::Matrix3d to_index = ct.index_to_P.inverse();
        int outside = 0;
        Eigen::Vector3d first = Eigen::Vector3d::Zero();
        for (const auto& p : t.points) {
          const Eigen::Vector3d ijk = to_index * (p - ct.origin_P);
          const bool in = (ijk.array() >= -0.5).all() && (ijk.array() <= ct.size.cast<double>().array() - 0.5).all();
          if (!in && outside++ == 0) first = p;
        }
        TROCAR_THROW_UNLESS(outside == 0, spec.markups << ": target '" << spec.name << "': " << outside << " of "
                                                       << t.points.size() << " points lie outside the CT "
                                                       << c.ct << " (the first at " << (first * 1e3).transpose()
                                                       << " mm, LPS); is this the same patient and frame?");
      }
      const bool from_file = spec.normals != "surface" && t.normals.size() == t.points.size();
      TROCAR_THROW_UNLESS(from_file || spec.normals != "file",
                          c.file << ": target '" << spec.name << "': normals: file, but "
                                 << spec.markups << " has no orientation for every point");
      if (from_file) {
        t.normals_from = "file";
      } else {
        const Structure* surface = m.Find(spec.surface);
        TROCAR_THROW_UNLESS(surface != nullptr,
                            c.file << ": target '" << spec.name << "': surface '" << spec.surface
                                   << "' is not a structure of this model (skin, ribs, sternum, "
                                      "spine, heart)");
        t.normals.clear();
        for (const auto& p : t.points) {
          const Eigen::Vector3d n = NearestSurfaceNormal(surface->mesh, p);
          t.normals.push_back(spec.inward ? -n : n);
        }
        t.normals_from = "surface:" + spec.surface + (spec.inward ? " (inward)" : "");
      }
      m.targets.push_back(std::move(t));
    }
  });
  stage("port candidates", [&] {
    for (const auto& file : c.port_markups) {
      for (const auto& mk : LoadMarkups(file)) {
        m.port_candidates.push_back({mk.name, mk.points, "markups:" + file});
      }
    }
    if (m.port_candidates.empty()) {
      for (const auto& space : FindIntercostalSpaces(ct, seg, c.intercostal)) {
        const auto& ribs = space.side > 0 ? seg.bones.ribs_left : seg.bones.ribs_right;
        int number = space.upper_rib + 1;  // by order, top to bottom
        if (seg.bones.numbered) {
          // The space below rib N is the Nth; ribs whose numbers are not consecutive (one not
          // labelled) bound no space that can be named.
          number = ribs[space.upper_rib].number;
          if (ribs[space.upper_rib + 1].number != number + 1) continue;
        }
        m.port_candidates.push_back({std::string(space.side > 0 ? "ICS-L" : "ICS-R") + std::to_string(number),
                                     space.skin, seg.bones.numbered ? "intercostal:labels" : "intercostal"});
      }
    }
  });
  {
    // No port on a crop face: points within the margin of a face the body is cut by go.
    const auto faces = FindCutFaces(ct, seg.body);
    std::vector<PortCandidate> kept;
    int dropped_points = 0, dropped_curves = 0;
    for (auto& cand : m.port_candidates) {
      Curve inside;
      for (const auto& p : cand.skin) {
        bool near = false;
        for (const auto& f : faces) near = near || DistanceToCutFace(ct, f, p) < PatientModel::kCutFaceMargin;
        if (near) {
          ++dropped_points;
        } else {
          inside.push_back(p);
        }
      }
      if (inside.size() >= 2) {
        cand.skin = std::move(inside);
        kept.push_back(std::move(cand));
      } else {
        ++dropped_curves;
      }
    }
    if (dropped_points > 0) {
      std::ostringstream w;
      w << "port candidates: " << dropped_points << " points";
      if (dropped_curves > 0) w << " (" << dropped_curves << " whole curves)";
      w << " lay within " << PatientModel::kCutFaceMargin * 1e3 << " mm of the scan's cut faces and were left out";
      m.warnings.push_back(w.str());
    }
    m.port_candidates = std::move(kept);
    if (m.port_candidates.empty()) {
      std::ostringstream w;
      w << "no port candidates: ";
      if (!c.port_markups.empty()) {
        w << "the annotated curves all lie at the scan's cut faces";
      } else if (dropped_curves > 0) {
        w << "the intercostal spaces found all lie at the scan's cut faces";
      } else {
        const int left = static_cast<int>(seg.bones.ribs_left.size()), right = static_cast<int>(seg.bones.ribs_right.size());
        w << "no intercostal space was found (ribs found: " << left << " left, " << right
          << " right; sides asked: " << (c.intercostal.left ? "left" : "") << (c.intercostal.left && c.intercostal.right ? ", " : "")
          << (c.intercostal.right ? "right" : "") << ")";
      }
      w << "; annotate them (port_candidates: in patient.yaml) or give a label map (labels:)";
      m.warnings.push_back(w.str());
    }
  }
  m.X_WP = PoseOnTable(m.Find("skin")->mesh, m.left_side_up, m.table);
  if (options.write_cache) {
    // A case folder one cannot write to (a read-only checkout) still gives its model.
    stage("write cache", [&] {
      try {
        WriteCacheFiles(m, cache_dir, key, ct.files);
      } catch (const Error& e) {
        m.cache_error = e.what();
      }
    });
  }
  m.timings = timings;
  return m;
}

}  // namespace trocar::patient
