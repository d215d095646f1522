#include "patient/model_cache.hpp"
#include "patient/model_code_version.hpp"

#include <algorithm>
#include <cctype>
#include <cstring>
#include <filesystem>
#include <sstream>

#include <zlib.h>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "patient/markups.hpp"

namespace trocar::patient {

// ---------------------------------------------------------------- serialisation
namespace {

constexpr char kMagic[8] = {'T', 'R', 'O', 'C', 'P', 'M', '0', '3'};

// CRC-32 (zlib) of everything before the checksum, with the length: a flipped byte anywhere
// (a pose, a vertex, the key) fails it.
std::uint64_t Checksum(const char* data, std::size_t n) {
  uLong crc = crc32_z(0L, Z_NULL, 0);
  crc = crc32_z(crc, reinterpret_cast<const Bytef*>(data), n);
  return (static_cast<std::uint64_t>(n) << 32) ^ static_cast<std::uint64_t>(crc);
}

}  // namespace

std::uint64_t ModelChecksum(const char* data, std::size_t n) { return Checksum(data, n); }

namespace {

struct CacheWriter {
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

std::string SerializeModel(const PatientModel& m, const ImportReport& report, std::uint64_t key) {
  CacheWriter w;
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
  for (const auto* lines : {&report.checks, &report.warnings, &m.cut_faces}) {
    w.Pod<std::uint64_t>(lines->size());
    for (const auto& line : *lines) w.Str(line);
  }
  w.Pod(Checksum(w.out.data(), w.out.size()));
  w.out.append(kMagic, 8);  // trailer: a truncated file never loads
  return w.out;
}

bool DeserializeModel(const std::string& bytes, std::uint64_t key, PatientModel* out, ImportReport* report,
                      std::string* damage) {
  auto damaged = [&](const char* why) {
    if (damage != nullptr) *damage = why;
    return false;
  };
  if (bytes.size() >= 8 && std::memcmp(bytes.data(), kMagic, 6) == 0 &&
      std::memcmp(bytes.data(), kMagic, 8) != 0) {
    return false;  // another version's cache: stale, rebuilt without a word
  }
  if (bytes.size() < 32 || std::memcmp(bytes.data(), kMagic, 8) != 0) {
    return damaged("not a trocar model cache");
  }
  if (std::memcmp(bytes.data() + bytes.size() - 8, kMagic, 8) != 0) {
    return damaged("truncated (no end marker)");
  }
  std::uint64_t stored = 0;
  std::memcpy(&stored, bytes.data() + bytes.size() - 16, 8);
  if (stored != Checksum(bytes.data(), bytes.size() - 16)) {
    return damaged("its checksum does not match its contents");
  }
  Reader r{bytes, 8};
  if (r.Pod<std::uint64_t>() != key) return false;  // stale: built from other inputs
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
  ImportReport said;
  for (auto* lines : {&said.checks, &said.warnings, &m.cut_faces}) {
    lines->resize(r.Count(8));
    for (auto& line : *lines) line = r.Str();
  }
  if (!r.ok || r.pos + 16 != bytes.size()) return damaged("its contents are inconsistent");
  *out = std::move(m);
  if (report != nullptr) {
    report->checks = std::move(said.checks);
    report->warnings = std::move(said.warnings);
  }
  return true;
}


namespace {

std::uint64_t Fnv1a(std::uint64_t h, const std::string& bytes) {
  for (unsigned char c : bytes) {
    h ^= c;
    h *= 1099511628211ull;
  }
  return h;
}

}  // namespace

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

namespace {

// Every file whose contents the model depends on: the case file, the CT's files (`ct_files`: what
// the CT reader read, a detached data file or a series' slices too), masks, label maps, markups.
std::vector<std::string> InputFiles(const CaseSpec& c, const std::vector<std::string>& ct_files) {
  std::vector<std::string> files = {c.file};
  files.insert(files.end(), ct_files.begin(), ct_files.end());
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

// The folder a DICOM CT's series is chosen from (the `ct:` folder, or the folder of the one .dcm
// file named), else empty: which slices the series holds depends on the whole folder.
std::string SeriesFolder(const std::string& ct) {
  if (std::filesystem::is_directory(ct)) return ct;
  std::string lower = ct;
  std::transform(lower.begin(), lower.end(), lower.begin(), [](unsigned char ch) { return std::tolower(ch); });
  if (lower.size() >= 4 && lower.compare(lower.size() - 4, 4, ".dcm") == 0) {
    return std::filesystem::path(ct).parent_path().string();
  }
  return "";
}

}  // namespace

const char* PatientModelCode() { return TROCAR_PATIENT_MODEL_CODE; }

std::uint64_t CacheKey(const CaseSpec& c, const std::vector<std::string>& ct_files) {
  // The format and the code that built the model: other code may build another model from the
  // same inputs.
  std::uint64_t h = Fnv1a(14695981039346656037ull, std::string("trocar patient model v5 ") + PatientModelCode());
  for (const auto& f : InputFiles(c, ct_files)) {
    h = Fnv1a(h, std::filesystem::path(f).filename().string());
    h = Fnv1a(h, ReadBinaryFile(f));
  }
  // A DICOM series' folder by its listing (names and sizes): a slice added or removed changes the
  // key, while the contents that matter, the series' own slices, are in ct_files above.
  const std::string folder = SeriesFolder(c.ct);
  if (!folder.empty()) {
    h = Fnv1a(h, "series folder");
    for (const auto& f : FolderFiles(folder)) {
      std::error_code ec;
      const auto size = std::filesystem::file_size(f, ec);
      h = Fnv1a(h, std::filesystem::path(f).filename().string() + ":" + (ec ? "?" : std::to_string(size)));
    }
  }
  return h;
}

// cache/ct_files.txt: the CT's files as the last build read them (absolute paths), so that a
// cached load keys the model without decoding the CT. Empty when absent, damaged or naming a file
// that is gone (the caller then reads the CT).
namespace {
constexpr char kCtFilesHeader[] = "trocar ct files v1";
}  // namespace

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

namespace {
std::string CtFilesText(const std::vector<std::string>& files) {
  std::string text = std::string(kCtFilesHeader) + "\n";
  for (const auto& f : files) text += std::filesystem::absolute(f).lexically_normal().string() + "\n";
  return text;
}
}  // namespace


void WriteCacheFiles(const PatientModel& m, const ImportReport& report, const std::string& cache_dir,
                     std::uint64_t key, const std::vector<std::string>& ct_files) {
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
  WriteFileAtomically(JoinPath(cache_dir, "model.bin"), SerializeModel(m, report, key));
}


}  // namespace trocar::patient
