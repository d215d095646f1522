#include "patient/label_map.hpp"

#include <cerrno>
#include <algorithm>
#include <cctype>
#include <cmath>
#include <filesystem>
#include <regex>
#include <set>
#include <sstream>

#include <nlohmann/json.hpp>

#include "common/error.hpp"
#include "common/json_util.hpp"
#include "common/file_util.hpp"

namespace trocar::patient {
namespace {

std::string Normalise(const std::string& name) {
  std::string n;
  for (char c : name) {
    const unsigned char u = static_cast<unsigned char>(c);
    n += (c == ' ' || c == '-' || c == '.') ? '_' : static_cast<char>(std::tolower(u));
  }
  return n;
}

bool Contains(const std::string& s, const char* part) { return s.find(part) != std::string::npos; }

int SideOf(const std::string& n) {
  if (Contains(n, "left")) return +1;
  if (Contains(n, "right")) return -1;
  return 0;
}

bool EndsWithText(const std::string& s, const std::string& end) {
  return s.size() >= end.size() && s.compare(s.size() - end.size(), end.size(), end) == 0;
}

// Names from TotalSegmentator's Caret XML label table: <Label Key="N" ...><![CDATA[name]]></Label>.
// A label value or segment index written as decimal digits, range-checked before it is
// narrowed (a 20-digit index was "internal error: stoi").
int SmallInteger(const std::string& digits, long lo, long hi, const std::string& where,
                 const std::string& what) {
  char* end = nullptr;
  errno = 0;
  const long long v = std::strtoll(digits.c_str(), &end, 10);
  TROCAR_THROW_UNLESS(!digits.empty() && end && *end == '\0' && errno == 0 && v >= lo && v <= hi,
                      where << ": " << what << " '" << digits.substr(0, 24) << "' is not in ["
                            << lo << ", " << hi << "]");
  return static_cast<int>(v);
}

std::map<int, std::string> NamesFromCaretXml(const std::string& xml, const std::string& where) {
  std::map<int, std::string> names;
  static const std::regex label(
      R"re(<Label\s+Key="(-?\d+)"[^>]*>\s*(?:<!\[CDATA\[([^\]]*)\]\]>|([^<]*))\s*</Label>)re");
  for (auto it = std::sregex_iterator(xml.begin(), xml.end(), label); it != std::sregex_iterator(); ++it) {
    const int key = SmallInteger((*it)[1].str(), -999999, 999999, where, "label table key");
    const std::string name = (*it)[2].matched ? (*it)[2].str() : (*it)[3].str();
    if (key != 0 && !name.empty()) names[key] = name;
  }
  return names;
}

std::map<int, std::string> NamesFromJson(const std::string& file) {
  nlohmann::json j;
  try {
    j = ReadJsonFile(file);
  } catch (const nlohmann::json::exception& e) {
    TROCAR_THROW(file << ": not JSON: " << e.what());
  }
  TROCAR_THROW_UNLESS(j.is_object(), file << ": expected an object {\"label value\": \"name\", ...}");
  std::map<int, std::string> names;
  for (auto it = j.begin(); it != j.end(); ++it) {
    // Either {"5": "liver"} (value → name) or {"liver": 5} (name → value).
    std::string key = it.key(), name;
    if (it.value().is_string()) {
      name = it.value().get<std::string>();
    } else if (it.value().is_number_integer()) {
      name = key;
      key = std::to_string(it.value().get<long>());
    } else {
      TROCAR_THROW(file << ": entry '" << key << "' is neither a name nor a label value");
    }
    char* end = nullptr;
    const long value = std::strtol(key.c_str(), &end, 10);
    TROCAR_THROW_UNLESS(!key.empty() && end && *end == '\0' && value > 0 && value < 1000000,
                        file << ": '" << key << "' is not a label value (a whole number 1..999999)");
    names[static_cast<int>(value)] = name;
  }
  return names;
}

bool IsVolumeFile(const std::string& name) {
  const std::string l = Normalise(name);
  return EndsWithText(l, "_nii_gz") || EndsWithText(l, "_nii") || EndsWithText(l, "_nrrd") ||
         EndsWithText(l, "_mha");
}

std::string StemOf(const std::string& file) {
  std::string stem = std::filesystem::path(file).filename().string();
  for (const char* ext : {".seg.nrrd", ".nii.gz", ".nii", ".nrrd", ".mha"}) {
    if (EndsWithText(stem, ext)) return stem.substr(0, stem.size() - std::string(ext).size());
  }
  return stem;
}

bool SameGrid(const Volume& a, const Volume& b) {
  return a.size == b.size && (a.index_to_P - b.index_to_P).norm() < 1e-7 && (a.origin_P - b.origin_P).norm() < 1e-6;
}

std::string Geometry(const Volume& v) {
  std::ostringstream s;
  const Eigen::Vector3d sp = v.spacing() * 1e3, o = v.origin_P * 1e3;
  const Eigen::Vector3d far = v.PatientPoint(v.size.x() - 1, v.size.y() - 1, v.size.z() - 1) * 1e3;
  s << v.size.x() << "x" << v.size.y() << "x" << v.size.z() << " voxels of " << sp.x() << " x " << sp.y()
    << " x " << sp.z() << " mm from (" << o.x() << ", " << o.y() << ", " << o.z() << ") to (" << far.x()
    << ", " << far.y() << ", " << far.z() << ") mm LPS";
  return s.str();
}

}  // namespace

LabelClass ClassifyLabel(const std::string& raw) {
  const std::string n = Normalise(raw);
  LabelClass c;
  static const std::regex rib(R"((?:^|_)ribs?(?:_|$))");
  if (std::regex_search(n, rib) && !Contains(n, "cartilage")) {
    static const std::regex number(R"((?:^|_)(\d{1,2})(?:_|$))");
    std::smatch m;
    const int side = SideOf(n);
    if (side != 0 && std::regex_search(n, m, number)) {
      const int k = std::stoi(m[1].str());
      if (k >= 1 && k <= 12) return {LabelKind::kRib, side, k};
    }
    return c;  // "ribs" as a whole, or unnumbered: not a numbered rib
  }
  if (Contains(n, "costal_cartilage")) return {LabelKind::kCartilage, 0, 0};
  if (n == "sternum" || Contains(n, "manubrium") || Contains(n, "xiphoid")) return {LabelKind::kSternum, 0, 0};
  if (Contains(n, "vertebra") || n == "sacrum" || Contains(n, "spine")) return {LabelKind::kVertebra, 0, 0};
  if (n == "heart" || Contains(n, "heart_") || Contains(n, "myocardium") || Contains(n, "atrial_appendage") ||
      (Contains(n, "atrium") || Contains(n, "ventricle"))) {
    if (!Contains(n, "brain")) return {LabelKind::kHeart, 0, 0};
  }
  for (const char* v : {"aorta", "pulmonary_artery", "pulmonary_trunk", "pulmonary_vein", "vena_cava",
                        "brachiocephalic", "subclavian_artery", "common_carotid", "iliac_artery",
                        "iliac_vena", "portal_vein", "azygos"}) {
    if (Contains(n, v)) return {LabelKind::kVessel, SideOf(n), 0};
  }
  for (const char* s : {"scapula", "clavicula", "clavicle", "humerus"}) {
    if (Contains(n, s)) return {LabelKind::kShoulder, SideOf(n), 0};
  }
  return c;
}

LabelMap LoadLabelMap(const std::string& path, const std::string& names_file) {
  namespace fs = std::filesystem;
  std::error_code ec;
  LabelMap map;
  map.source = path;
  if (fs::is_directory(path, ec)) {
    // A folder of masks, one structure each, named by the file (TotalSegmentator's default).
    std::vector<std::string> files;
    for (fs::directory_iterator it(path, ec), end; !ec && it != end; it.increment(ec)) {
      if (it->is_regular_file(ec) && IsVolumeFile(it->path().filename().string())) files.push_back(it->path().string());
    }
    TROCAR_THROW_UNLESS(!ec, path << ": cannot list the folder: " << ec.message());
    std::sort(files.begin(), files.end());
    TROCAR_THROW_UNLESS(!files.empty(), path << ": a label folder holds one mask per structure "
                                                "(<name>.nii.gz, .nii, .nrrd or .mha); none found");
    int value = 0;
    for (const auto& f : files) {
      const std::string name = StemOf(f);
      // Masks trocar does not use are not read (TotalSegmentator writes over a hundred).
      if (ClassifyLabel(name).kind == LabelKind::kOther) continue;
      Volume mask = LoadVolume(f);
      if (map.volume.values.empty()) {
        map.volume = mask;
        std::fill(map.volume.values.begin(), map.volume.values.end(), 0.0f);
        map.volume.files.clear();
        map.volume.source = path;
      }
      TROCAR_THROW_UNLESS(SameGrid(mask, map.volume),
                          f << ": on a different grid than the folder's other masks (" << Geometry(mask)
                            << " against " << Geometry(map.volume) << ")");
      ++value;
      map.names[value] = name;
      for (std::size_t n = 0; n < mask.values.size(); ++n) {
        if (mask.values[n] > 0.5f) map.volume.values[n] = static_cast<float>(value);
      }
      map.volume.files.push_back(f);
    }
    TROCAR_THROW_UNLESS(value > 0, path << ": none of its " << files.size()
                                        << " masks is a structure trocar uses (ribs, sternum, costal "
                                           "cartilages, vertebrae, heart, vessels), e.g. "
                                        << StemOf(files.front()));
    TROCAR_THROW_UNLESS(std::any_of(map.volume.values.begin(), map.volume.values.end(),
                                    [](float x) { return x > 0.0f; }),
                        path << ": the label map labels no voxel (each of its " << value
                             << " masks that trocar uses is empty)");
    return map;
  }
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": label map not found");
  map.volume = LoadVolume(path);
  // Names: a sidecar given or found beside, then the file's own metadata.
  std::string sidecar = names_file;
  if (sidecar.empty()) {
    const std::string guess = JoinPath(ParentDirectory(path), StemOf(path) + ".json");
    if (IsRegularFile(guess)) sidecar = guess;
  }
  if (!sidecar.empty()) {
    map.names = NamesFromJson(sidecar);
    map.volume.files.push_back(sidecar);
  }
  if (map.names.empty()) {
    for (const auto& [code, content] : map.volume.extensions) {
      if (content.find("<Label") != std::string::npos)
        map.names = NamesFromCaretXml(content, path + " (header extension " + std::to_string(code) + ")");
      if (!map.names.empty()) break;
    }
  }
  if (map.names.empty()) {
    // 3D Slicer: SegmentN_Name, SegmentN_LabelValue (default N+1), SegmentN_Layer (must be 0).
    std::map<int, std::map<std::string, std::string>> segments;
    static const std::regex key(R"(Segment(\d+)_(Name|LabelValue|Layer))");
    for (const auto& [k, v] : map.volume.key_values) {
      std::smatch m;
      if (std::regex_match(k, m, key))
        segments[SmallInteger(m[1].str(), 0, 999999, path, "segment index in key " + k.substr(0, 40))]
                [m[2].str()] = v;
    }
    for (const auto& [index, fields] : segments) {
      if (!fields.count("Name")) continue;
      const std::string layer = fields.count("Layer") ? fields.at("Layer") : "0";
      TROCAR_THROW_UNLESS(layer == "0", path << ": segment " << index << " ('" << fields.at("Name")
                                             << "') is on layer " << layer
                                             << "; trocar reads one-layer segmentations (in 3D Slicer: "
                                                "Segmentations > export to a labelmap)");
      const std::string value = fields.count("LabelValue") ? fields.at("LabelValue") : std::to_string(index + 1);
      char* end = nullptr;
      const long v = std::strtol(value.c_str(), &end, 10);
      TROCAR_THROW_UNLESS(!value.empty() && end && *end == '\0' && v > 0 && v < 1000000,
                          path << ": Segment" << index << "_LabelValue '" << value << "' is not a label value");
      map.names[static_cast<int>(v)] = fields.at("Name");
    }
  }
  TROCAR_THROW_UNLESS(!map.names.empty(),
                      path << ": the label map names no labels (expected TotalSegmentator's label table "
                              "in the NIfTI header extension, 3D Slicer's SegmentN_Name keys, or a JSON "
                              "sidecar "
                           << JoinPath(ParentDirectory(path), StemOf(path) + ".json")
                           << " mapping values to names)");
  // Values present in the volume but unnamed are an error: a wrong sidecar would misread them.
  std::set<int> present;
  for (float x : map.volume.values) {
    TROCAR_THROW_UNLESS(x == std::round(x) && x >= 0 && x < 1e6,
                        path << ": value " << x << " is not a label (a whole number 0..999999)");
    if (x > 0) present.insert(static_cast<int>(x));
  }
  std::ostringstream unnamed;
  int count = 0;
  for (int v : present) {
    if (!map.names.count(v) && count++ < 10) unnamed << (count > 1 ? ", " : "") << v;
  }
  TROCAR_THROW_UNLESS(count == 0, path << ": " << count << " label value(s) have no name (" << unnamed.str()
                                       << (count > 10 ? ", ..." : "") << ")");
  // A map that labels nothing would be ignored without a word and the anatomy taken from the CT
  // alone (one that labels nothing trocar uses is refused by AnatomyFromLabels).
  TROCAR_THROW_UNLESS(!present.empty(),
                      path << ": the label map labels no voxel (every value is 0); its names ("
                           << map.names.size() << ") label nothing in it");
  return map;
}

std::vector<int> ResampleLabels(const LabelMap& map, const Volume& grid) {
  const Volume& m = map.volume;
  std::vector<int> out(static_cast<std::size_t>(grid.voxel_count()), 0);
  if (SameGrid(m, grid)) {
    for (std::size_t n = 0; n < out.size(); ++n) out[n] = static_cast<int>(m.values[n]);
    return out;
  }
  const Eigen::Matrix3d to_index = m.index_to_P.inverse();
  long inside = 0;
  for (int k = 0; k < grid.size.z(); ++k) {
    for (int j = 0; j < grid.size.y(); ++j) {
      for (int i = 0; i < grid.size.x(); ++i) {
        const Eigen::Vector3d q = to_index * (grid.PatientPoint(i, j, k) - m.origin_P);
        const Eigen::Vector3i r(static_cast<int>(std::lround(q.x())), static_cast<int>(std::lround(q.y())),
                                static_cast<int>(std::lround(q.z())));
        if ((r.array() < 0).any() || (r.array() >= m.size.array()).any()) continue;
        ++inside;
        out[grid.Index(i, j, k)] = static_cast<int>(m.at(r.x(), r.y(), r.z()));
      }
    }
  }
  TROCAR_THROW_UNLESS(inside > 0, map.source << ": the label map (" << Geometry(m) << ") does not overlap the CT "
                                             << grid.source << " (" << Geometry(grid) << ")");
  return out;
}

LabelAgreement MeasureLabelAgreement(const Volume& ct, const BoneParts& bones,
                                     double bone_threshold) {
  LabelAgreement a;
  std::vector<std::uint8_t> is_rib;
  int top = 0;
  for (const auto* side : {&bones.ribs_left, &bones.ribs_right})
    for (const Component& c : *side) top = std::max(top, c.label);
  is_rib.assign(static_cast<std::size_t>(top) + 1, 0);
  for (const auto* side : {&bones.ribs_left, &bones.ribs_right})
    for (const Component& c : *side) is_rib[c.label] = 1;
  std::vector<Eigen::Vector3i> voxels;
  for (int k = 0; k < ct.size.z(); ++k)
    for (int j = 0; j < ct.size.y(); ++j)
      for (int i = 0; i < ct.size.x(); ++i) {
        const int l = bones.labels[ct.Index(i, j, k)];
        if (l > 0 && l <= top && is_rib[l]) voxels.emplace_back(i, j, k);
      }
  a.rib_voxels = static_cast<long>(voxels.size());
  if (voxels.empty()) return a;
  auto share = [&](const Eigen::Vector3i& d) {
    long bright = 0;
    for (const Eigen::Vector3i& v : voxels) {
      const Eigen::Vector3i w = v + d;
      if ((w.array() < 0).any() || (w.array() >= ct.size.array()).any()) continue;
      bright += ct.values[ct.Index(w.x(), w.y(), w.z())] > bone_threshold;
    }
    return static_cast<double>(bright) / static_cast<double>(voxels.size());
  };
  a.here = a.best = share(Eigen::Vector3i::Zero());
  for (int axis = 0; axis < 3; ++axis) {
    const double step = ct.index_to_P.col(axis).norm();
    for (const double mm :
         {-30.0, -25.0, -20.0, -15.0, -10.0, -5.0, 5.0, 10.0, 15.0, 20.0, 25.0, 30.0}) {
      Eigen::Vector3i d = Eigen::Vector3i::Zero();
      d[axis] = static_cast<int>(std::lround(mm * 1e-3 / step));
      if (d[axis] == 0) continue;
      const double s = share(d);
      if (s > a.best) {
        a.best = s;
        a.best_move_P = ct.index_to_P * d.cast<double>();
      }
    }
  }
  return a;
}

LabelledAnatomy AnatomyFromLabels(const LabelMap& map, const Volume& ct) {
  LabelledAnatomy a;
  std::map<int, LabelClass> classes;
  for (const auto& [value, name] : map.names) {
    const LabelClass c = ClassifyLabel(name);
    classes[value] = c;
    (c.kind == LabelKind::kOther ? a.unused : a.used).push_back(name);
  }
  if (a.used.empty()) {
    std::ostringstream list;
    int shown = 0;
    for (const auto& [value, name] : map.names) {
      if (shown++ < 12) list << (shown > 1 ? ", " : "") << value << " " << name;
    }
    TROCAR_THROW(map.source << ": none of its " << map.names.size()
                            << " label names is a structure trocar uses (rib_left_1..rib_right_12, "
                               "sternum, costal_cartilages, vertebrae_*, heart or its chambers, aorta "
                               "and great vessels, scapula/clavicula/humerus); it has: "
                            << list.str() << (map.names.size() > 12 ? ", ..." : ""));
  }
  const std::vector<int> labels = ResampleLabels(map, ct);
  // Bone components: one per labelled rib (side, number), one for the sternum with the costal
  // cartilages, one for the vertebrae. Component labels are 1.. in that order.
  struct Part {
    LabelKind kind;
    int side, number;
  };
  std::vector<Part> parts;
  std::map<int, int> part_of_value;
  auto part_index = [&](const LabelClass& c) {
    const LabelKind kind = c.kind == LabelKind::kCartilage ? LabelKind::kSternum : c.kind;
    for (std::size_t p = 0; p < parts.size(); ++p) {
      if (parts[p].kind == kind && parts[p].side == (kind == LabelKind::kRib ? c.side : 0) &&
          parts[p].number == c.number)
        return static_cast<int>(p);
    }
    parts.push_back({kind, kind == LabelKind::kRib ? c.side : 0, c.number});
    return static_cast<int>(parts.size()) - 1;
  };
  for (const auto& [value, c] : classes) {
    if (c.kind == LabelKind::kRib || c.kind == LabelKind::kSternum || c.kind == LabelKind::kCartilage ||
        c.kind == LabelKind::kVertebra)
      part_of_value[value] = part_index(c);
  }
  a.heart.size = a.vessels.size = a.shoulder.size = ct.size;
  a.heart.inside.assign(labels.size(), 0);
  a.vessels.inside.assign(labels.size(), 0);
  a.shoulder.inside.assign(labels.size(), 0);
  a.bones.labels.assign(labels.size(), 0);
  std::vector<Component> comps(parts.size());
  std::vector<Eigen::Vector3d> sum(parts.size(), Eigen::Vector3d::Zero());
  std::vector<Eigen::Vector3i> lo(parts.size(), ct.size), hi(parts.size(), Eigen::Vector3i::Constant(-1));
  for (long n = 0; n < static_cast<long>(labels.size()); ++n) {
    const int value = labels[n];
    if (value == 0) continue;
    const auto cls = classes.find(value);
    if (cls == classes.end()) continue;
    switch (cls->second.kind) {
      case LabelKind::kHeart: a.heart.inside[n] = 1; break;
      case LabelKind::kVessel: a.vessels.inside[n] = 1; break;
      case LabelKind::kShoulder: a.shoulder.inside[n] = 1; break;
      default: break;
    }
    const auto part = part_of_value.find(value);
    if (part == part_of_value.end()) continue;
    const int p = part->second;
    a.bones.labels[n] = p + 1;
    const Eigen::Vector3i ijk(static_cast<int>(n % ct.size.x()), static_cast<int>((n / ct.size.x()) % ct.size.y()),
                              static_cast<int>(n / (static_cast<long>(ct.size.x()) * ct.size.y())));
    ++comps[p].voxels;
    sum[p] += ijk.cast<double>();
    lo[p] = lo[p].cwiseMin(ijk);
    hi[p] = hi[p].cwiseMax(ijk);
  }
  const double voxel_volume = std::abs(ct.index_to_P.determinant());
  for (std::size_t p = 0; p < parts.size(); ++p) {
    Component& c = comps[p];
    if (c.voxels == 0) continue;  // named but not on the CT
    c.label = static_cast<int>(p) + 1;
    c.number = parts[p].number;
    c.volume = c.voxels * voxel_volume;
    const Eigen::Vector3d mean = sum[p] / static_cast<double>(c.voxels);
    c.centroid_P = ct.PatientPoint(mean.x(), mean.y(), mean.z());
    c.min_P = Eigen::Vector3d::Constant(HUGE_VAL);
    c.max_P = -c.min_P;
    for (int corner = 0; corner < 8; ++corner) {
      const Eigen::Vector3d q = ct.PatientPoint(corner & 1 ? hi[p].x() : lo[p].x(), corner & 2 ? hi[p].y() : lo[p].y(),
                                                corner & 4 ? hi[p].z() : lo[p].z());
      c.min_P = c.min_P.cwiseMin(q);
      c.max_P = c.max_P.cwiseMax(q);
    }
    switch (parts[p].kind) {
      case LabelKind::kRib: (parts[p].side > 0 ? a.bones.ribs_left : a.bones.ribs_right).push_back(c); break;
      case LabelKind::kSternum: a.bones.sternum.push_back(c); break;
      default: a.bones.spine.push_back(c); break;
    }
  }
  auto by_number = [](const Component& x, const Component& y) { return x.number < y.number; };
  std::sort(a.bones.ribs_left.begin(), a.bones.ribs_left.end(), by_number);
  std::sort(a.bones.ribs_right.begin(), a.bones.ribs_right.end(), by_number);
  a.bones.numbered = true;
  return a;
}

}  // namespace trocar::patient
