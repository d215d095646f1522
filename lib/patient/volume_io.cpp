#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <iomanip>
#include <filesystem>
#include <map>
#include <sstream>

#include <zlib.h>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "common/limits.hpp"
#include "patient/volume.hpp"

namespace trocar::patient {
namespace {

enum class VoxelType { kUint8, kInt8, kInt16, kUint16, kInt32, kUint32, kFloat32, kFloat64 };

int BytesOf(VoxelType t) {
  switch (t) {
    case VoxelType::kUint8:
    case VoxelType::kInt8: return 1;
    case VoxelType::kInt16:
    case VoxelType::kUint16: return 2;
    case VoxelType::kInt32:
    case VoxelType::kUint32:
    case VoxelType::kFloat32: return 4;
    case VoxelType::kFloat64: return 8;
  }
  return 1;
}

bool IsSigned(VoxelType t) {
  return t == VoxelType::kInt8 || t == VoxelType::kInt16 || t == VoxelType::kInt32 ||
         t == VoxelType::kFloat32 || t == VoxelType::kFloat64;
}

bool EndsWith(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

std::string Trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  return s.substr(b, s.find_last_not_of(" \t\r\n") - b + 1);
}

std::string Lower(std::string s) {
  std::transform(s.begin(), s.end(), s.begin(), [](unsigned char c) { return std::tolower(c); });
  return s;
}

// gzip or zlib, detected from the stream. Never produces more than `max_out` bytes: beyond it
// the stream holds more than the header describes (a decompression bomb among others) and the
// read stops with an error naming the bound, unless `prefix_only`, which returns the first
// `max_out` bytes (a header to size the rest by).
std::string Inflate(const std::string& data, const std::string& what, std::uint64_t max_out,
                    bool prefix_only = false) {
  z_stream stream{};
  TROCAR_THROW_UNLESS(inflateInit2(&stream, 15 + 32) == Z_OK, what << ": cannot start decompression");
  const auto* next = reinterpret_cast<const Bytef*>(data.data());
  std::size_t left = data.size();
  std::string out;
  char buffer[1 << 16];
  int status = Z_OK;
  bool too_long = false;
  auto feed = [&] {  // zlib counts input in uInt: hand it at most 1 GiB at a time
    if (stream.avail_in == 0 && left > 0) {
      const std::size_t piece = std::min<std::size_t>(left, std::size_t{1} << 30);
      stream.next_in = const_cast<Bytef*>(next);
      stream.avail_in = static_cast<uInt>(piece);
      next += piece;
      left -= piece;
    }
  };
  auto append = [&](std::size_t n) {
    if (out.size() + n > max_out) {
      out.append(buffer, static_cast<std::size_t>(max_out - out.size()));
      too_long = true;
      return false;
    }
    out.append(buffer, n);
    return true;
  };
  while (status == Z_OK) {
    feed();
    stream.next_out = reinterpret_cast<Bytef*>(buffer);
    stream.avail_out = sizeof(buffer);
    status = inflate(&stream, Z_NO_FLUSH);
    if (status != Z_OK && status != Z_STREAM_END) break;
    if (!append(sizeof(buffer) - stream.avail_out)) break;
    if (status == Z_STREAM_END && (stream.avail_in > 0 || left > 0)) {
      // Concatenated gzip members: continue with the next one.
      inflateReset(&stream);
      status = Z_OK;
      continue;
    }
    if (status == Z_OK && stream.avail_in == 0 && left == 0 && stream.avail_out != 0) {
      status = Z_BUF_ERROR;  // input ended before the stream did
    }
  }
  const std::string message = stream.msg ? stream.msg : std::to_string(status);
  inflateEnd(&stream);
  if (too_long) {
    TROCAR_THROW_UNLESS(prefix_only, what << ": compressed data inflates to more than the "
                                          << max_out << " bytes its header describes");
    return out;
  }
  if (prefix_only && out.size() == max_out) return out;
  TROCAR_THROW_UNLESS(status == Z_STREAM_END,
                      what << ": compressed data is "
                           << (status == Z_BUF_ERROR ? "truncated" : "corrupt") << " (zlib "
                           << message << ")");
  return out;
}

// Raw voxel bytes → floats, checking the count and that every value is finite.
std::vector<float> Convert(const std::string& bytes, std::size_t offset, VoxelType type,
                           bool big_endian, std::uint64_t count, double slope, double intercept,
                           const std::string& what) {
  const int n = BytesOf(type);
  const std::size_t needed = static_cast<std::size_t>(count) * n;  // count ≤ max_voxels: no overflow
  TROCAR_THROW_UNLESS(bytes.size() >= offset && bytes.size() - offset >= needed,
                      what << ": voxel data is truncated: " << (bytes.size() >= offset ? bytes.size() - offset : 0)
                           << " bytes, expected " << needed);
  TROCAR_THROW_UNLESS(bytes.size() - offset == needed,
                      what << ": voxel data has " << bytes.size() - offset - needed
                           << " bytes more than the " << needed << " its header describes");
  std::vector<float> values(static_cast<std::size_t>(count));
  const unsigned char* p = reinterpret_cast<const unsigned char*>(bytes.data()) + offset;
  unsigned char word[8];
  long bad = 0;
  for (std::uint64_t v = 0; v < count; ++v, p += n) {
    for (int b = 0; b < n; ++b) word[b] = big_endian ? p[n - 1 - b] : p[b];
    double x = 0.0;
    switch (type) {
      case VoxelType::kUint8: x = word[0]; break;
      case VoxelType::kInt8: x = static_cast<std::int8_t>(word[0]); break;
      case VoxelType::kInt16: { std::int16_t t; std::memcpy(&t, word, 2); x = t; break; }
      case VoxelType::kUint16: { std::uint16_t t; std::memcpy(&t, word, 2); x = t; break; }
      case VoxelType::kInt32: { std::int32_t t; std::memcpy(&t, word, 4); x = t; break; }
      case VoxelType::kUint32: { std::uint32_t t; std::memcpy(&t, word, 4); x = t; break; }
      case VoxelType::kFloat32: { float t; std::memcpy(&t, word, 4); x = t; break; }
      case VoxelType::kFloat64: { double t; std::memcpy(&t, word, 8); x = t; break; }
    }
    x = slope * x + intercept;
    if (!std::isfinite(x)) ++bad;
    values[static_cast<std::size_t>(v)] = static_cast<float>(x);
  }
  TROCAR_THROW_UNLESS(bad == 0, what << ": " << bad << " voxels are NaN or infinite");
  return values;
}

// Hounsfield units are recognised by signed data reaching into air (−1000 HU).
bool LooksLikeHounsfield(VoxelType type, const std::vector<float>& values) {
  if (!IsSigned(type) || values.empty()) return false;
  return *std::min_element(values.begin(), values.end()) <= -500.0f;
}

}  // namespace

bool LooksLikeCtNumbersWithoutIntercept(const Volume& v, double* soft_tissue) {
  if (v.values.empty()) return false;
  const auto [lo, hi] = std::minmax_element(v.values.begin(), v.values.end());
  if (*lo < 0.0f || *hi < 1500.0f) return false;
  // Every 7th voxel is plenty for shares of a volume's tissues.
  long air = 0, rest = 0;
  std::vector<float> soft;
  for (std::size_t n = 0; n < v.values.size(); n += 7) {
    const float x = v.values[n];
    if (x <= 300.0f) {
      ++air;
    } else {
      ++rest;
      if (x >= 850.0f && x <= 1200.0f) soft.push_back(x);
    }
  }
  const long all = air + rest;
  if (air < 0.05 * static_cast<double>(all) || rest == 0 ||
      static_cast<double>(soft.size()) < 0.4 * static_cast<double>(rest))
    return false;
  if (soft_tissue != nullptr) {
    std::nth_element(soft.begin(), soft.begin() + soft.size() / 2, soft.end());
    *soft_tissue = soft[soft.size() / 2];
  }
  return true;
}

namespace {

// Sizes, spacing and directions as CheckVolumeGeometry, returning the voxel count.
std::uint64_t CheckGeometry(const Volume& v, const std::string& what) {
  CheckVolumeGeometry(v, what);
  return CheckedVoxelCount(v.size, what);
}

// ---------------------------------------------------------------------------------------------
// NRRD

VoxelType NrrdType(const std::string& raw, const std::string& what) {
  const std::string t = Lower(Trim(raw));
  static const std::map<std::string, VoxelType> types = {
      {"uchar", VoxelType::kUint8},  {"unsigned char", VoxelType::kUint8},
      {"uint8", VoxelType::kUint8},  {"uint8_t", VoxelType::kUint8},
      {"signed char", VoxelType::kInt8}, {"int8", VoxelType::kInt8}, {"int8_t", VoxelType::kInt8},
      {"short", VoxelType::kInt16},  {"short int", VoxelType::kInt16},
      {"signed short", VoxelType::kInt16}, {"int16", VoxelType::kInt16}, {"int16_t", VoxelType::kInt16},
      {"ushort", VoxelType::kUint16}, {"unsigned short", VoxelType::kUint16},
      {"uint16", VoxelType::kUint16}, {"uint16_t", VoxelType::kUint16},
      {"int", VoxelType::kInt32},    {"int32", VoxelType::kInt32}, {"int32_t", VoxelType::kInt32},
      {"signed int", VoxelType::kInt32},
      {"uint", VoxelType::kUint32},  {"unsigned int", VoxelType::kUint32},
      {"uint32", VoxelType::kUint32}, {"uint32_t", VoxelType::kUint32},
      {"float", VoxelType::kFloat32}, {"double", VoxelType::kFloat64}};
  const auto it = types.find(t);
  TROCAR_THROW_UNLESS(it != types.end(), what << ": field 'type': '" << raw
                                              << "' is not a supported voxel type");
  return it->second;
}

Eigen::Vector3d ParseVector(const std::string& raw, const std::string& what) {
  std::string s = raw;
  for (char& c : s) {
    if (c == '(' || c == ')' || c == ',') c = ' ';
  }
  std::istringstream in(s);
  Eigen::Vector3d v;
  TROCAR_THROW_UNLESS(static_cast<bool>(in >> v.x() >> v.y() >> v.z()),
                      what << ": expected a vector (x,y,z), got '" << raw << "'");
  std::string rest;
  TROCAR_THROW_UNLESS(!(in >> rest), what << ": expected a 3-vector, got '" << raw << "'");
  return v;
}

std::vector<std::string> SplitVectors(const std::string& raw) {
  std::vector<std::string> out;
  std::size_t at = 0;
  while ((at = raw.find('(', at)) != std::string::npos) {
    const std::size_t end = raw.find(')', at);
    if (end == std::string::npos) break;
    out.push_back(raw.substr(at, end - at + 1));
    at = end + 1;
  }
  return out;
}

// A header is read before the data it describes, at most this much of it.
constexpr std::size_t kMaxHeaderBytes = std::size_t{1} << 20;

// The data a header declares, checked against the file that holds it before that file is read
// (issue #44, item 2: a 128-byte header over a 3 GB data file read the 3 GB before its error).
// Raw data must be exactly the `needed` bytes past `offset`, as Convert requires (the same
// messages); a compressed file can be at most a little larger than what it inflates to (deflate's
// stored blocks add 5 bytes per 64 KiB, gzip a header and a trailer per member).
void CheckDeclaredSize(const std::string& file, std::uint64_t offset, std::uint64_t needed,
                       bool compressed) {
  const std::uint64_t size = RegularFileSize(file);
  if (compressed) {
    const std::uint64_t most = offset + needed + (offset + needed) / 100 + (std::uint64_t{64} << 10);
    TROCAR_THROW_UNLESS(size <= most, file << ": " << size
                                           << " bytes of compressed data, more than a stream of "
                                              "the "
                                           << offset + needed
                                           << " bytes its header describes can take");
    return;
  }
  TROCAR_THROW_UNLESS(size >= offset && size - offset >= needed,
                      file << ": voxel data is truncated: " << (size >= offset ? size - offset : 0)
                           << " bytes, expected " << needed);
  TROCAR_THROW_UNLESS(size - offset == needed,
                      file << ": voxel data has " << size - offset - needed << " bytes more than the "
                           << needed << " its header describes");
}

// A header read as a prefix of its file: it must end within the prefix (a blank line, or the
// line naming the data) unless the prefix is the whole file.
void CheckHeaderEnded(const std::string& path, const std::string& prefix, bool ended) {
  TROCAR_THROW_UNLESS(ended || prefix.size() == RegularFileSize(path) ||
                          RegularFileSize(path) <= kMaxHeaderBytes,
                      path << ": its header does not end within its first " << kMaxHeaderBytes
                           << " bytes");
}

// A header's prefix cut at its last complete line when the file goes on past it.
std::string HeaderPrefix(const std::string& path) {
  std::string text = ReadFilePrefix(path, kMaxHeaderBytes);
  if (text.size() < RegularFileSize(path)) {
    const std::size_t last = text.rfind('\n');
    text.resize(last == std::string::npos ? 0 : last + 1);
  }
  return text;
}

Volume LoadNrrd(const std::string& path) {
  const std::string text = HeaderPrefix(path);
  TROCAR_THROW_UNLESS(text.rfind("NRRD000", 0) == 0,
                      path << ": not a NRRD file (it must start with NRRD000x)");
  std::map<std::string, std::string> fields;
  std::vector<std::pair<std::string, std::string>> key_values;
  std::size_t at = text.find('\n') + 1;
  std::size_t data_start = std::string::npos;
  while (at < text.size()) {
    std::size_t end = text.find('\n', at);
    if (end == std::string::npos) end = text.size();
    const std::string line = text.substr(at, end - at);
    at = end + 1;
    if (Trim(line).empty()) {
      data_start = at;  // attached data follows the blank line
      break;
    }
    if (line[0] == '#') continue;
    if (const auto kv = line.find(":="); kv != std::string::npos) {  // key/value pairs
      key_values.emplace_back(line.substr(0, kv), line.substr(kv + 2));
      continue;
    }
    const std::size_t colon = line.find(": ");
    TROCAR_THROW_UNLESS(colon != std::string::npos,
                        path << ": header line '" << Trim(line) << "' is not 'field: value'");
    fields[Lower(Trim(line.substr(0, colon)))] = Trim(line.substr(colon + 2));
  }
  CheckHeaderEnded(path, text, data_start != std::string::npos);
  auto field = [&](const std::string& name) -> const std::string& {
    const auto it = fields.find(name);
    TROCAR_THROW_UNLESS(it != fields.end(), path << ": missing field '" << name << "'");
    return it->second;
  };
  const std::string where = path;
  const VoxelType type = NrrdType(field("type"), where);
  TROCAR_THROW_UNLESS(Trim(field("dimension")) == "3",
                      path << ": field 'dimension': " << field("dimension")
                           << " (only 3-D volumes are supported)");
  Volume v;
  v.key_values = std::move(key_values);
  v.source = path;
  {
    std::istringstream in(field("sizes"));
    TROCAR_THROW_UNLESS(static_cast<bool>(in >> v.size.x() >> v.size.y() >> v.size.z()),
                        path << ": field 'sizes': expected three integers, got '" << field("sizes") << "'");
  }
  double flip = 1.0;  // RAS → LPS negates x and y
  Eigen::Matrix3d directions_mm = Eigen::Matrix3d::Identity();
  Eigen::Vector3d origin_mm = Eigen::Vector3d::Zero();
  if (fields.count("space")) {
    const std::string space = Lower(field("space"));
    if (space == "left-posterior-superior" || space == "lps") {
      flip = 1.0;
    } else if (space == "right-anterior-superior" || space == "ras") {
      flip = -1.0;
    } else {
      TROCAR_THROW(path << ": field 'space': '" << field("space")
                        << "' (expected left-posterior-superior or right-anterior-superior)");
    }
    const auto vectors = SplitVectors(field("space directions"));
    TROCAR_THROW_UNLESS(vectors.size() == 3, path << ": field 'space directions': expected three "
                                                     "vectors (x,y,z), got '"
                                                  << field("space directions") << "'");
    for (int a = 0; a < 3; ++a) {
      directions_mm.col(a) = ParseVector(vectors[a], path + ": field 'space directions'");
    }
    if (fields.count("space origin")) {
      origin_mm = ParseVector(field("space origin"), path + ": field 'space origin'");
    }
  } else {
    // No space: axis-aligned with "spacings" (or 1 mm), taken as LPS.
    if (fields.count("spacings")) {
      std::istringstream in(field("spacings"));
      Eigen::Vector3d s;
      TROCAR_THROW_UNLESS(static_cast<bool>(in >> s.x() >> s.y() >> s.z()),
                          path << ": field 'spacings': expected three numbers");
      directions_mm = s.asDiagonal();
    }
  }
  const Eigen::Vector3d to_lps(flip, flip, 1.0);
  v.index_to_P = to_lps.asDiagonal() * directions_mm * kMillimetre;
  v.origin_P = to_lps.asDiagonal() * origin_mm * kMillimetre;
  if (fields.count("space units")) {
    const std::string units = Lower(field("space units"));
    TROCAR_THROW_UNLESS(units.find("mm") != std::string::npos,
                        path << ": field 'space units': '" << field("space units")
                             << "' (only millimetres are supported)");
  }
  const std::uint64_t count = CheckGeometry(v, path);

  const std::string encoding = Lower(field("encoding"));
  TROCAR_THROW_UNLESS(encoding == "raw" || encoding == "gzip" || encoding == "gz",
                      path << ": field 'encoding': '" << field("encoding")
                           << "' (expected raw or gzip)");
  const bool big_endian = fields.count("endian") && Lower(field("endian")) == "big";
  std::string data;
  std::string data_name = path;
  if (fields.count("data file") || fields.count("datafile")) {
    const std::string name = fields.count("data file") ? field("data file") : field("datafile");
    TROCAR_THROW_UNLESS(name.find(' ') == std::string::npos || name.rfind("LIST", 0) != 0,
                        path << ": field 'data file': multi-file data is not supported");
    data_name = JoinPath(ParentDirectory(path), name);
    TROCAR_THROW_UNLESS(IsRegularFile(data_name), path << ": field 'data file': '" << name
                                                       << "' not found (looked for " << data_name << ")");
    CheckDeclaredSize(data_name, 0, count * BytesOf(type), encoding != "raw");
    data = ReadBinaryFile(data_name);
    v.files.push_back(data_name);
  } else {
    TROCAR_THROW_UNLESS(data_start != std::string::npos,
                        path << ": no attached data and no 'data file' field");
    CheckDeclaredSize(path, data_start, count * BytesOf(type), encoding != "raw");
    data = ReadBinaryFile(path).substr(data_start);
  }
  if (encoding != "raw") data = Inflate(data, data_name, count * BytesOf(type));
  v.values = Convert(data, 0, type, big_endian, count, 1.0, 0.0, data_name);
  v.hounsfield = LooksLikeHounsfield(type, v.values);
  return v;
}

// ---------------------------------------------------------------------------------------------
// NIfTI-1

Volume LoadNifti(const std::string& path) {
  // The header first, to size the rest: the file is checked against it before the voxels are
  // read, and they never inflate past what it describes.
  std::string bytes = ReadFilePrefix(path, kMaxHeaderBytes);
  const bool gzipped = EndsWith(Lower(path), ".gz");
  if (gzipped) bytes = Inflate(bytes, path, 352, /*prefix_only=*/true);
  TROCAR_THROW_UNLESS(bytes.size() >= 352, path << ": too short for a NIfTI-1 header ("
                                                << bytes.size() << " bytes)");
  std::int32_t header_size;
  std::memcpy(&header_size, bytes.data(), 4);
  bool swap = false;
  if (header_size != 348) {
    std::uint32_t u;
    std::memcpy(&u, bytes.data(), 4);
    u = ((u & 0xff) << 24) | ((u & 0xff00) << 8) | ((u >> 8) & 0xff00) | (u >> 24);
    TROCAR_THROW_UNLESS(u == 348, path << ": not a NIfTI-1 file (sizeof_hdr " << header_size
                                       << ", expected 348)");
    swap = true;
  }
  auto read = [&](std::size_t offset, int n) {
    unsigned char w[8];
    for (int b = 0; b < n; ++b) {
      w[b] = static_cast<unsigned char>(bytes[offset + (swap ? n - 1 - b : b)]);
    }
    return std::string(reinterpret_cast<char*>(w), n);
  };
  auto i16 = [&](std::size_t o) { std::int16_t v; std::memcpy(&v, read(o, 2).data(), 2); return v; };
  auto f32 = [&](std::size_t o) { float v; std::memcpy(&v, read(o, 4).data(), 4); return static_cast<double>(v); };
  const std::string magic = bytes.substr(344, 3);
  TROCAR_THROW_UNLESS(magic == "n+1", path << ": NIfTI magic '" << magic
                                           << "' (only single-file .nii, magic n+1, is supported)");
  const int ndim = i16(40);
  TROCAR_THROW_UNLESS(ndim == 3 || (ndim == 4 && i16(48) == 1),
                      path << ": dim[0] = " << ndim << " (only 3-D volumes are supported)");
  Volume v;
  v.source = path;
  v.size << i16(42), i16(44), i16(46);
  VoxelType type;
  switch (i16(70)) {
    case 2: type = VoxelType::kUint8; break;
    case 4: type = VoxelType::kInt16; break;
    case 8: type = VoxelType::kInt32; break;
    case 16: type = VoxelType::kFloat32; break;
    case 64: type = VoxelType::kFloat64; break;
    case 256: type = VoxelType::kInt8; break;
    case 512: type = VoxelType::kUint16; break;
    case 768: type = VoxelType::kUint32; break;
    default: TROCAR_THROW(path << ": datatype " << i16(70) << " is not supported");
  }
  double pixdim[8];
  for (int k = 0; k < 8; ++k) pixdim[k] = f32(76 + 4 * k);
  const double vox_offset = f32(108);
  double slope = f32(112), intercept = f32(116);
  if (slope == 0.0 || !std::isfinite(slope)) {
    slope = 1.0;
    intercept = 0.0;
  }
  const int qform = i16(252), sform = i16(254);
  Eigen::Matrix3d directions_mm;
  Eigen::Vector3d origin_mm;
  if (sform > 0) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) directions_mm(r, c) = f32(280 + 16 * r + 4 * c);
      origin_mm[r] = f32(280 + 16 * r + 12);
    }
  } else if (qform > 0) {
    // As the NIfTI reference code (nifti1_io.c, nifti_quatern_to_mat44): a = sqrt(1 − b² − c² −
    // d²), and when b² + c² + d² reaches 1 the vector part is normalised and a = 0 (a 180°
    // rotation). Used as it is, a longer quaternion scales and shears the voxel axes.
    double b = f32(256), c = f32(260), d = f32(264);
    const double norm2 = b * b + c * c + d * d;
    TROCAR_THROW_UNLESS(std::isfinite(norm2),
                        path << ": qform quaternion (" << b << ", " << c << ", " << d
                             << ") is not finite");
    double a = 1.0 - norm2;
    if (a < 1e-7) {
      if (norm2 > 1.0 + 1e-6) {
        std::ostringstream w;
        w << path << ": qform quaternion (b, c, d) = (" << b << ", " << c << ", " << d
          << ") has b² + c² + d² = " << norm2
          << " > 1; normalised as the NIfTI reference code does (a 180° rotation): check the "
             "orientation";
        v.warnings.push_back(w.str());
      }
      const double scale = 1.0 / std::sqrt(norm2);
      b *= scale;
      c *= scale;
      d *= scale;
      a = 0.0;
    } else {
      a = std::sqrt(a);
    }
    const Eigen::Matrix3d R = Eigen::Quaterniond(a, b, c, d).normalized().toRotationMatrix();
    const double qfac = pixdim[0] < 0 ? -1.0 : 1.0;
    directions_mm = R * Eigen::Vector3d(pixdim[1], pixdim[2], qfac * pixdim[3]).asDiagonal();
    origin_mm << f32(268), f32(272), f32(276);
  } else {
    directions_mm = Eigen::Vector3d(pixdim[1], pixdim[2], pixdim[3]).asDiagonal();
    origin_mm.setZero();
  }
  // NIfTI world coordinates are RAS millimetres.
  const Eigen::Vector3d to_lps(-1.0, -1.0, 1.0);
  v.index_to_P = to_lps.asDiagonal() * directions_mm * kMillimetre;
  v.origin_P = to_lps.asDiagonal() * origin_mm * kMillimetre;
  const std::uint64_t count = CheckGeometry(v, path);
  TROCAR_THROW_UNLESS(std::isfinite(vox_offset) && vox_offset >= 348 && vox_offset < 1e9,
                      path << ": vox_offset " << vox_offset << " is not just past the header");
  const std::size_t data_offset = static_cast<std::size_t>(vox_offset);
  CheckDeclaredSize(path, data_offset, count * BytesOf(type), gzipped);
  bytes = gzipped ? Inflate(ReadBinaryFile(path), path, data_offset + count * BytesOf(type))
                  : ReadBinaryFile(path);
  TROCAR_THROW_UNLESS(bytes.size() >= data_offset,
                      path << ": " << bytes.size() << " bytes, shorter than its vox_offset "
                           << data_offset);
  // Convert() assumes little-endian bytes after our own swap of the header only: voxel data
  // follow the header's byte order.
  const bool big_endian = swap;
  // Header extensions (a label map's names, e.g. TotalSegmentator's Caret XML label table):
  // records of (size, code, content) from byte 352 up to the voxels.
  if (bytes[348] != 0) {
    std::size_t pos = 352;
    auto i32 = [&](std::size_t o) {
      std::int32_t x;
      std::memcpy(&x, read(o, 4).data(), 4);
      return x;
    };
    while (pos + 8 <= data_offset) {
      const std::int32_t esize = i32(pos), ecode = i32(pos + 4);
      if (esize < 16 || esize % 16 != 0 || pos + esize > data_offset) {
        break;  // not an extension record: the rest is padding
      }
      std::string content = bytes.substr(pos + 8, static_cast<std::size_t>(esize) - 8);
      content.erase(std::find(content.begin(), content.end(), '\0'), content.end());
      v.extensions.emplace_back(ecode, std::move(content));
      pos += static_cast<std::size_t>(esize);
    }
  }
  v.values = Convert(bytes, data_offset, type, big_endian, count, slope, intercept, path);
  v.hounsfield = LooksLikeHounsfield(type, v.values);
  return v;
}

// ---------------------------------------------------------------------------------------------
// MetaImage

Volume LoadMetaImage(const std::string& path) {
  const std::string text = HeaderPrefix(path);
  std::map<std::string, std::string> fields;
  std::size_t at = 0;
  std::size_t data_start = std::string::npos;
  while (at < text.size()) {
    std::size_t end = text.find('\n', at);
    if (end == std::string::npos) end = text.size();
    const std::string line = text.substr(at, end - at);
    at = end + 1;
    if (Trim(line).empty()) continue;
    const std::size_t eq = line.find('=');
    TROCAR_THROW_UNLESS(eq != std::string::npos,
                        path << ": header line '" << Trim(line).substr(0, 60) << "' is not 'Key = Value'");
    const std::string key = Trim(line.substr(0, eq));
    fields[key] = Trim(line.substr(eq + 1));
    if (key == "ElementDataFile") {
      data_start = at;
      break;
    }
  }
  CheckHeaderEnded(path, text, data_start != std::string::npos);
  auto field = [&](const std::string& name) -> const std::string& {
    const auto it = fields.find(name);
    TROCAR_THROW_UNLESS(it != fields.end(), path << ": missing field '" << name << "'");
    return it->second;
  };
  TROCAR_THROW_UNLESS(Trim(field("NDims")) == "3",
                      path << ": field 'NDims': " << field("NDims") << " (only 3-D volumes)");
  if (fields.count("ElementNumberOfChannels")) {
    TROCAR_THROW_UNLESS(Trim(field("ElementNumberOfChannels")) == "1",
                        path << ": field 'ElementNumberOfChannels' must be 1");
  }
  Volume v;
  v.source = path;
  {
    std::istringstream in(field("DimSize"));
    TROCAR_THROW_UNLESS(static_cast<bool>(in >> v.size.x() >> v.size.y() >> v.size.z()),
                        path << ": field 'DimSize': expected three integers");
  }
  // Three numbers from the first of `keys` present, or `fallback`.
  auto triple = [&](std::initializer_list<const char*> keys, const Eigen::Vector3d& fallback) {
    for (const char* key : keys) {
      if (!fields.count(key)) continue;
      std::istringstream in(fields[key]);
      Eigen::Vector3d v;
      TROCAR_THROW_UNLESS(static_cast<bool>(in >> v.x() >> v.y() >> v.z()),
                          path << ": field '" << key << "': expected three numbers");
      return v;
    }
    return fallback;
  };
  const Eigen::Vector3d spacing = triple({"ElementSpacing", "ElementSize"}, Eigen::Vector3d::Ones());
  const Eigen::Vector3d origin_mm = triple({"Offset", "Origin", "Position"}, Eigen::Vector3d::Zero());
  Eigen::Matrix3d directions = Eigen::Matrix3d::Identity();
  for (const char* key : {"TransformMatrix", "Rotation", "Orientation"}) {
    if (!fields.count(key)) continue;
    std::istringstream in(fields[key]);
    // Axis i's direction is the i-th triple (ITK writes the direction matrix column by column).
    for (int c = 0; c < 3; ++c) {
      for (int r = 0; r < 3; ++r) {
        TROCAR_THROW_UNLESS(static_cast<bool>(in >> directions(r, c)),
                            path << ": field '" << key << "': expected nine numbers");
      }
    }
  }
  // MetaImage physical space is LPS millimetres (ITK's convention).
  v.index_to_P = directions * spacing.asDiagonal() * kMillimetre;
  v.origin_P = origin_mm * kMillimetre;
  const std::uint64_t count = CheckGeometry(v, path);
  static const std::map<std::string, VoxelType> types = {
      {"MET_UCHAR", VoxelType::kUint8},  {"MET_CHAR", VoxelType::kInt8},
      {"MET_SHORT", VoxelType::kInt16},  {"MET_USHORT", VoxelType::kUint16},
      {"MET_INT", VoxelType::kInt32},    {"MET_UINT", VoxelType::kUint32},
      {"MET_FLOAT", VoxelType::kFloat32}, {"MET_DOUBLE", VoxelType::kFloat64}};
  const auto type_it = types.find(field("ElementType"));
  TROCAR_THROW_UNLESS(type_it != types.end(), path << ": field 'ElementType': '"
                                                   << field("ElementType") << "' is not supported");
  bool big_endian = false;
  for (const char* key : {"BinaryDataByteOrderMSB", "ElementByteOrderMSB"}) {
    if (fields.count(key)) big_endian = Lower(fields[key]) == "true";
  }
  const std::string file = field("ElementDataFile");
  std::string data;
  std::string data_name = path;
  const bool compressed =
      fields.count("CompressedData") && Lower(fields["CompressedData"]) == "true";
  if (file == "LOCAL") {
    TROCAR_THROW_UNLESS(data_start != std::string::npos && data_start <= text.size(),
                        path << ": ElementDataFile = LOCAL but no data follows");
    CheckDeclaredSize(path, data_start, count * BytesOf(type_it->second), compressed);
    data = ReadBinaryFile(path).substr(data_start);
  } else {
    data_name = JoinPath(ParentDirectory(path), file);
    TROCAR_THROW_UNLESS(IsRegularFile(data_name), path << ": field 'ElementDataFile': '" << file
                                                       << "' not found (looked for " << data_name << ")");
    CheckDeclaredSize(data_name, 0, count * BytesOf(type_it->second), compressed);
    data = ReadBinaryFile(data_name);
    v.files.push_back(data_name);
  }
  if (fields.count("CompressedData") && Lower(fields["CompressedData"]) == "true") {
    data = Inflate(data, data_name, count * BytesOf(type_it->second));
  }
  v.values = Convert(data, 0, type_it->second, big_endian, count, 1.0, 0.0, data_name);
  v.hounsfield = LooksLikeHounsfield(type_it->second, v.values);
  return v;
}

std::string Deflate(const std::string& data, bool gzip) {
  z_stream stream{};
  TROCAR_THROW_UNLESS(deflateInit2(&stream, 6, Z_DEFLATED, 15 + (gzip ? 16 : 0), 8,
                                   Z_DEFAULT_STRATEGY) == Z_OK,
                      "cannot start compression");
  stream.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
  stream.avail_in = static_cast<uInt>(data.size());
  std::string out(deflateBound(&stream, static_cast<uLong>(data.size())), '\0');
  stream.next_out = reinterpret_cast<Bytef*>(&out[0]);
  stream.avail_out = static_cast<uInt>(out.size());
  const int status = deflate(&stream, Z_FINISH);
  out.resize(stream.total_out);
  deflateEnd(&stream);
  TROCAR_THROW_UNLESS(status == Z_STREAM_END, "compression failed");
  return out;
}

}  // namespace

void CheckVolumeGeometry(const Volume& v, const std::string& what) {
  TROCAR_THROW_UNLESS((v.size.array() > 0).all(), what << ": sizes " << v.size.transpose()
                                                       << " must be positive");
  TROCAR_THROW_UNLESS(v.index_to_P.allFinite() && v.origin_P.allFinite(),
                      what << ": spacing, directions or origin is not finite");
  const Eigen::Vector3d spacing = v.spacing();
  static const char* kAxis[3] = {"i (columns)", "j (rows)", "k (slices)"};
  for (int a = 0; a < 3; ++a) {
    TROCAR_THROW_UNLESS(spacing[a] >= 1e-6 && spacing[a] <= 0.1,
                        what << ": voxel size along " << kAxis[a] << " is " << spacing[a] * 1e3
                             << " mm, outside 0.001–100 mm (a damaged header, or units other "
                                "than millimetres?)");
  }
  TROCAR_THROW_UNLESS(
      std::abs(v.index_to_P.determinant()) > 1e-3 * spacing.prod(),
      what << ": the voxel axes are degenerate (parallel or nearly parallel directions)");
  TROCAR_THROW_UNLESS(v.origin_P.cwiseAbs().maxCoeff() < 100.0,
                      what << ": origin " << v.origin_P.transpose() * 1e3
                           << " mm is more than 100 m from the scanner's origin");
}

Image RenderSlice(const Volume& v, int axis, int index, double level, double width) {
  TROCAR_THROW_UNLESS(axis >= 0 && axis <= 2 && index >= 0 && index < v.size[axis],
                      "slice " << index << " on axis " << axis << " is outside the volume");
  // Image axes: u (columns), w (rows, drawn downward from the top).
  const int u_axis = axis == 0 ? 1 : 0;
  const int w_axis = axis == 2 ? 1 : 2;
  const Eigen::Vector3d spacing = v.spacing();
  const double pixel = spacing.minCoeff();
  Image image;
  image.width = static_cast<int>(std::lround(v.size[u_axis] * spacing[u_axis] / pixel));
  image.height = static_cast<int>(std::lround(v.size[w_axis] * spacing[w_axis] / pixel));
  image.rgb.resize(3 * static_cast<std::size_t>(image.width) * image.height);
  // Which way is up: anterior (−y in LPS) for axial, superior (+z) otherwise.
  const Eigen::Vector3d up = axis == 2 ? Eigen::Vector3d(0, -1, 0) : Eigen::Vector3d(0, 0, 1);
  const bool flip = v.index_to_P.col(w_axis).dot(up) > 0;  // index grows upward: draw reversed
  const Eigen::Vector3d right = axis == 0 ? Eigen::Vector3d(0, -1, 0) : Eigen::Vector3d(-1, 0, 0);
  // Radiological convention: the patient's right on the image's left, so columns run toward the
  // patient's left; reverse them when the index grows toward the patient's right.
  const bool mirror = v.index_to_P.col(u_axis).dot(right) > 0;
  for (int r = 0; r < image.height; ++r) {
    for (int c = 0; c < image.width; ++c) {
      int iu = std::min(v.size[u_axis] - 1, static_cast<int>(c * pixel / spacing[u_axis]));
      int iw = std::min(v.size[w_axis] - 1, static_cast<int>(r * pixel / spacing[w_axis]));
      if (flip) iw = v.size[w_axis] - 1 - iw;
      if (mirror) iu = v.size[u_axis] - 1 - iu;
      Eigen::Vector3i ijk;
      ijk[axis] = index;
      ijk[u_axis] = iu;
      ijk[w_axis] = iw;
      const double x = (v.at(ijk.x(), ijk.y(), ijk.z()) - (level - 0.5 * width)) / width;
      const auto grey = static_cast<unsigned char>(std::lround(255.0 * std::clamp(x, 0.0, 1.0)));
      const std::size_t at = 3 * (static_cast<std::size_t>(r) * image.width + c);
      image.rgb[at] = image.rgb[at + 1] = image.rgb[at + 2] = grey;
    }
  }
  return image;
}

Volume LoadVolume(const std::string& path) {
  std::error_code ec;
  const std::string name = Lower(path);
  if (std::filesystem::is_directory(path, ec) || (EndsWith(name, ".dcm") && IsRegularFile(path))) {
    return LoadDicomSeries(path);
  }
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": CT volume not found");
  Volume v;
  if (EndsWith(name, ".nrrd") || EndsWith(name, ".nhdr")) {
    v = LoadNrrd(path);
  } else if (EndsWith(name, ".nii") || EndsWith(name, ".nii.gz")) {
    v = LoadNifti(path);
  } else if (EndsWith(name, ".mha") || EndsWith(name, ".mhd")) {
    v = LoadMetaImage(path);
  } else {
    TROCAR_THROW(path << ": unknown volume format (expected .nrrd, .nhdr, .nii, .nii.gz, .mha, "
                       ".mhd, or a DICOM folder or .dcm file)");
  }
  v.files.insert(v.files.begin(), path);
  return v;
}

void WriteNrrd(const Volume& volume, const std::string& path, bool ras) {
  TROCAR_THROW_UNLESS(static_cast<long>(volume.values.size()) == volume.voxel_count(),
                      path << ": volume has " << volume.values.size() << " values for "
                           << volume.voxel_count() << " voxels");
  const Eigen::Vector3d to_space(ras ? -1.0 : 1.0, ras ? -1.0 : 1.0, 1.0);
  const Eigen::Matrix3d directions_mm = to_space.asDiagonal() * volume.index_to_P / kMillimetre;
  const Eigen::Vector3d origin_mm = to_space.asDiagonal() * volume.origin_P / kMillimetre;
  std::ostringstream header;
  header << std::setprecision(12) << "NRRD0004\n# written by trocar\ntype: float\ndimension: 3\n"
         << "space: " << (ras ? "right-anterior-superior" : "left-posterior-superior") << "\n"
         << "sizes: " << volume.size.x() << " " << volume.size.y() << " " << volume.size.z() << "\n"
         << "space directions:";
  for (int c = 0; c < 3; ++c) {
    header << " (" << directions_mm(0, c) << "," << directions_mm(1, c) << "," << directions_mm(2, c) << ")";
  }
  header << "\nspace origin: (" << origin_mm.x() << "," << origin_mm.y() << "," << origin_mm.z()
         << ")\nendian: little\nencoding: gzip\n\n";
  std::string raw(volume.values.size() * sizeof(float), '\0');
  std::memcpy(&raw[0], volume.values.data(), raw.size());
  WriteFileAtomically(path, header.str() + Deflate(raw, true));
}

}  // namespace trocar::patient
