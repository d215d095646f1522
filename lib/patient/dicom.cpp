// DICOM series: a small reader and writer for classic single-frame CT slices in uncompressed
// little-endian transfer syntaxes (implicit and explicit VR), the form in which scanners, PACS
// exports and TCIA collections deliver CT. Compressed (encapsulated) syntaxes are refused by name.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <map>
#include <sstream>

#include <unistd.h>

#include "common/error.hpp"
#include "common/file_util.hpp"
#include "patient/volume.hpp"

namespace trocar::patient {
namespace {

constexpr double kMillimetre = 1e-3;
constexpr std::uint32_t kUndefinedLength = 0xFFFFFFFFu;
constexpr int kMaxSequenceDepth = 16;

constexpr std::uint32_t Tag(std::uint16_t group, std::uint16_t element) {
  return (static_cast<std::uint32_t>(group) << 16) | element;
}
constexpr std::uint32_t kTransferSyntax = Tag(0x0002, 0x0010);
constexpr std::uint32_t kModality = Tag(0x0008, 0x0060);
constexpr std::uint32_t kSopClass = Tag(0x0008, 0x0016);
constexpr std::uint32_t kSeriesUid = Tag(0x0020, 0x000E);
constexpr std::uint32_t kInstanceNumber = Tag(0x0020, 0x0013);
constexpr std::uint32_t kPosition = Tag(0x0020, 0x0032);
constexpr std::uint32_t kOrientation = Tag(0x0020, 0x0037);
constexpr std::uint32_t kSamplesPerPixel = Tag(0x0028, 0x0002);
constexpr std::uint32_t kPhotometric = Tag(0x0028, 0x0004);
constexpr std::uint32_t kFrames = Tag(0x0028, 0x0008);
constexpr std::uint32_t kRows = Tag(0x0028, 0x0010);
constexpr std::uint32_t kColumns = Tag(0x0028, 0x0011);
constexpr std::uint32_t kPixelSpacing = Tag(0x0028, 0x0030);
constexpr std::uint32_t kBitsAllocated = Tag(0x0028, 0x0100);
constexpr std::uint32_t kBitsStored = Tag(0x0028, 0x0101);
constexpr std::uint32_t kPixelRepresentation = Tag(0x0028, 0x0103);
constexpr std::uint32_t kRescaleIntercept = Tag(0x0028, 0x1052);
constexpr std::uint32_t kRescaleSlope = Tag(0x0028, 0x1053);
constexpr std::uint32_t kPixelData = Tag(0x7FE0, 0x0010);

constexpr const char* kImplicitLittle = "1.2.840.10008.1.2";
constexpr const char* kExplicitLittle = "1.2.840.10008.1.2.1";
constexpr const char* kCtImageStorage = "1.2.840.10008.5.1.4.1.1.2";

std::string TagName(std::uint32_t tag) {
  std::ostringstream s;
  s << "(" << std::hex << std::uppercase;
  s.width(4);
  s.fill('0');
  s << (tag >> 16) << ",";
  s.width(4);
  s << (tag & 0xFFFF) << ")";
  return s.str();
}

// What a transfer syntax UID is called, for the refusal message.
std::string TransferSyntaxName(const std::string& uid) {
  static const std::map<std::string, std::string> names = {
      {"1.2.840.10008.1.2.1.99", "Deflated Explicit VR Little Endian"},
      {"1.2.840.10008.1.2.2", "Explicit VR Big Endian"},
      {"1.2.840.10008.1.2.4.50", "JPEG Baseline"},
      {"1.2.840.10008.1.2.4.51", "JPEG Extended"},
      {"1.2.840.10008.1.2.4.57", "JPEG Lossless"},
      {"1.2.840.10008.1.2.4.70", "JPEG Lossless SV1"},
      {"1.2.840.10008.1.2.4.80", "JPEG-LS Lossless"},
      {"1.2.840.10008.1.2.4.81", "JPEG-LS Near-Lossless"},
      {"1.2.840.10008.1.2.4.90", "JPEG 2000 Lossless"},
      {"1.2.840.10008.1.2.4.91", "JPEG 2000"},
      {"1.2.840.10008.1.2.4.201", "HTJ2K Lossless"},
      {"1.2.840.10008.1.2.4.203", "HTJ2K"},
      {"1.2.840.10008.1.2.5", "RLE Lossless"},
  };
  const auto it = names.find(uid);
  return it == names.end() ? "unknown transfer syntax" : it->second;
}

bool HasLongLength(const char vr[2]) {
  static const char* kLong[] = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ",
                                "UC", "UN", "UR", "UT", "SV", "UV"};
  for (const char* l : kLong) {
    if (vr[0] == l[0] && vr[1] == l[1]) return true;
  }
  return false;
}

// Top-level elements of one file: their byte ranges in the file.
struct Range {
  std::size_t offset = 0;
  std::uint32_t length = 0;
};

class Parser {
 public:
  Parser(const std::string& bytes, const std::string& file) : bytes_(bytes), file_(file) {}

  std::uint16_t U16(std::size_t at) const {
    Need(at, 2);
    return static_cast<std::uint16_t>(Byte(at) | (Byte(at + 1) << 8));
  }
  std::uint32_t U32(std::size_t at) const {
    Need(at, 4);
    return static_cast<std::uint32_t>(Byte(at)) | (static_cast<std::uint32_t>(Byte(at + 1)) << 8) |
           (static_cast<std::uint32_t>(Byte(at + 2)) << 16) |
           (static_cast<std::uint32_t>(Byte(at + 3)) << 24);
  }

  // Reads the element header at `pos`; returns its tag, sets the value's range and moves `pos`
  // to the value.
  std::uint32_t Header(std::size_t& pos, bool explicit_vr, Range& value) const {
    const std::uint32_t tag = Tag(U16(pos), U16(pos + 2));
    pos += 4;
    if ((tag >> 16) == 0xFFFE || !explicit_vr) {  // items and delimiters never carry a VR
      value.length = U32(pos);
      pos += 4;
    } else {
      Need(pos, 2);
      const char vr[2] = {bytes_[pos], bytes_[pos + 1]};
      TROCAR_THROW_UNLESS(std::isupper(static_cast<unsigned char>(vr[0])) &&
                              std::isupper(static_cast<unsigned char>(vr[1])),
                          file_ << ": element " << TagName(tag) << " at byte " << pos - 4
                                << " has no value representation (garbled or not explicit VR)");
      if (HasLongLength(vr)) {
        value.length = U32(pos + 4);
        pos += 8;
      } else {
        value.length = U16(pos + 2);
        pos += 4;
      }
    }
    value.offset = pos;
    return tag;
  }

  // Skips a value of undefined length (a sequence) starting at `pos`.
  void SkipSequence(std::size_t& pos, bool explicit_vr, int depth) const {
    TROCAR_THROW_UNLESS(depth < kMaxSequenceDepth, file_ << ": sequences nested deeper than "
                                                         << kMaxSequenceDepth << " (garbled file)");
    for (;;) {
      Range item;
      const std::uint32_t tag = Header(pos, false, item);
      if (tag == Tag(0xFFFE, 0xE0DD)) return;  // sequence delimiter
      TROCAR_THROW_UNLESS(tag == Tag(0xFFFE, 0xE000), file_ << ": expected a sequence item at byte "
                                                            << pos - 8 << ", found "
                                                            << TagName(tag));
      if (item.length != kUndefinedLength) {
        Skip(pos, item.length);
        continue;
      }
      for (;;) {  // item of undefined length: elements up to the item delimiter
        Range value;
        const std::uint32_t inner = Header(pos, explicit_vr, value);
        if (inner == Tag(0xFFFE, 0xE00D)) break;
        if (value.length == kUndefinedLength) {
          SkipSequence(pos, explicit_vr, depth + 1);
        } else {
          Skip(pos, value.length);
        }
      }
    }
  }

  void Skip(std::size_t& pos, std::uint32_t length) const {
    Need(pos, length);
    pos += length;
  }

  bool Has(std::size_t at, std::size_t n) const {
    return at <= bytes_.size() && bytes_.size() - at >= n;
  }

 private:
  unsigned Byte(std::size_t at) const { return static_cast<unsigned char>(bytes_[at]); }
  void Need(std::size_t at, std::size_t n) const {
    TROCAR_THROW_UNLESS(Has(at, n), file_ << ": truncated: needs " << n << " bytes at byte " << at
                                          << " but the file has " << bytes_.size());
  }

  const std::string& bytes_;
  const std::string& file_;
};

struct Slice {
  std::string file;
  std::string series_uid;
  std::string modality;
  int rows = 0, columns = 0;
  int bits_allocated = 0, bits_stored = 0;
  bool is_signed = false;
  double slope = 1.0, intercept = 0.0;
  Eigen::Vector3d position_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d row_direction = Eigen::Vector3d::UnitX();     // along increasing column index
  Eigen::Vector3d column_direction = Eigen::Vector3d::UnitY();  // along increasing row index
  Eigen::Vector2d spacing_mm = Eigen::Vector2d::Ones();         // between rows, between columns
  int instance = 0;
  std::string pixels;  // raw pixel bytes
};

std::string Text(const std::string& bytes, const Range& r) {
  std::string s = bytes.substr(r.offset, r.length);
  while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
  const auto b = s.find_first_not_of(' ');
  return b == std::string::npos ? "" : s.substr(b);
}

std::vector<double> Numbers(const std::string& text, std::size_t expected, const std::string& file,
                            const std::string& field) {
  std::vector<double> out;
  std::stringstream in(text);
  std::string part;
  while (std::getline(in, part, '\\')) {
    char* end = nullptr;
    const double x = std::strtod(part.c_str(), &end);
    while (end && *end == ' ') ++end;
    TROCAR_THROW_UNLESS(!part.empty() && end && *end == '\0' && std::isfinite(x),
                        file << ": " << field << " '" << text << "' is not a list of numbers");
    out.push_back(x);
  }
  TROCAR_THROW_UNLESS(out.size() == expected, file << ": " << field << " has " << out.size()
                                                   << " values, expected " << expected);
  return out;
}

// Reads one file. Returns false when it is not DICOM at all (no "DICM" magic and no plausible
// dataset start), so that folders may hold a README or a DICOMDIR beside the slices.
bool ReadSlice(const std::string& file, Slice& s) {
  const std::string bytes = ReadTextFile(file);
  Parser parser(bytes, file);
  std::size_t pos = 0;
  std::string transfer_syntax;
  if (bytes.size() >= 132 && bytes.compare(128, 4, "DICM") == 0) {
    pos = 132;
    // File meta information: always explicit VR little endian, group 0002.
    while (parser.Has(pos, 2) && parser.U16(pos) == 0x0002) {
      Range value;
      const std::uint32_t tag = parser.Header(pos, true, value);
      parser.Skip(pos, value.length);
      if (tag == kTransferSyntax) transfer_syntax = Text(bytes, value);
    }
    TROCAR_THROW_UNLESS(!transfer_syntax.empty(), file << ": file meta information has no transfer "
                                                          "syntax (0002,0010)");
  } else if (bytes.size() >= 8 && (bytes[0] == 0x08 && bytes[1] == 0x00)) {
    // A bare dataset without preamble (old ACR-NEMA style): implicit VR little endian.
    transfer_syntax = kImplicitLittle;
  } else {
    return false;
  }
  TROCAR_THROW_UNLESS(transfer_syntax == kImplicitLittle || transfer_syntax == kExplicitLittle,
                      file << ": transfer syntax " << transfer_syntax << " ("
                           << TransferSyntaxName(transfer_syntax)
                           << ") is not supported; trocar reads uncompressed little-endian DICOM. "
                              "Decompress the series first (e.g. `gdcmconv --raw` or `dcmdjpeg`)");
  const bool explicit_vr = transfer_syntax == kExplicitLittle;

  std::map<std::uint32_t, Range> elements;
  bool has_pixels = false;
  while (parser.Has(pos, 1)) {
    Range value;
    const std::uint32_t tag = parser.Header(pos, explicit_vr, value);
    if (tag == kPixelData) {
      TROCAR_THROW_UNLESS(value.length != kUndefinedLength,
                          file << ": pixel data (7FE0,0010) is encapsulated (compressed) although "
                                  "the transfer syntax says uncompressed");
      TROCAR_THROW_UNLESS(parser.Has(value.offset, value.length),
                          file << ": pixel data (7FE0,0010) is truncated: " << value.length
                               << " bytes declared, " << bytes.size() - value.offset << " present");
      elements[tag] = value;
      has_pixels = true;
      break;
    }
    if (value.length == kUndefinedLength) {
      parser.SkipSequence(pos, explicit_vr, 0);
    } else {
      parser.Skip(pos, value.length);
      elements[tag] = value;
    }
  }
  s.file = file;
  auto text = [&](std::uint32_t tag) {
    const auto it = elements.find(tag);
    return it == elements.end() ? std::string() : Text(bytes, it->second);
  };
  auto require = [&](std::uint32_t tag, const char* name) {
    TROCAR_THROW_UNLESS(elements.count(tag), file << ": missing " << name << " " << TagName(tag));
    return elements.at(tag);
  };
  auto unsigned_short = [&](std::uint32_t tag, const char* name) {
    const Range r = require(tag, name);
    TROCAR_THROW_UNLESS(r.length == 2, file << ": " << name << " " << TagName(tag) << " has "
                                            << r.length << " bytes, expected 2 (US)");
    return static_cast<int>(parser.U16(r.offset));
  };
  s.series_uid = text(kSeriesUid);
  s.modality = text(kModality);
  if (!has_pixels) {
    // A DICOMDIR, a structured report, a presentation state: not an image slice. A file with
    // image attributes but no pixel data was cut short.
    TROCAR_THROW_UNLESS(!elements.count(kRows), file << ": image with no pixel data (7FE0,0010) "
                                                        "(truncated?)");
    return false;
  }
  const std::string frames = text(kFrames);
  TROCAR_THROW_UNLESS(frames.empty() || frames == "1",
                      file << ": multi-frame image (" << frames << " frames, number of frames "
                           << TagName(kFrames)
                           << "); trocar reads classic one-slice-per-file series");
  const int samples =
      elements.count(kSamplesPerPixel) ? unsigned_short(kSamplesPerPixel, "samples per pixel") : 1;
  TROCAR_THROW_UNLESS(samples == 1, file << ": samples per pixel " << TagName(kSamplesPerPixel)
                                         << " is " << samples << ", expected 1 (a grey-level CT)");
  const std::string photometric = text(kPhotometric);
  TROCAR_THROW_UNLESS(
      photometric.empty() || photometric == "MONOCHROME2" || photometric == "MONOCHROME1",
      file << ": photometric interpretation " << TagName(kPhotometric) << " '" << photometric
           << "', expected MONOCHROME2");
  s.rows = unsigned_short(kRows, "rows");
  s.columns = unsigned_short(kColumns, "columns");
  TROCAR_THROW_UNLESS(s.rows > 0 && s.columns > 0,
                      file << ": image is " << s.rows << " x " << s.columns << " pixels");
  s.bits_allocated = unsigned_short(kBitsAllocated, "bits allocated");
  TROCAR_THROW_UNLESS(s.bits_allocated == 8 || s.bits_allocated == 16 || s.bits_allocated == 32,
                      file << ": bits allocated " << TagName(kBitsAllocated) << " is "
                           << s.bits_allocated << ", expected 8, 16 or 32");
  s.bits_stored =
      elements.count(kBitsStored) ? unsigned_short(kBitsStored, "bits stored") : s.bits_allocated;
  TROCAR_THROW_UNLESS(s.bits_stored >= 1 && s.bits_stored <= s.bits_allocated,
                      file << ": bits stored " << TagName(kBitsStored) << " is " << s.bits_stored
                           << ", expected 1 to " << s.bits_allocated);
  s.is_signed = unsigned_short(kPixelRepresentation, "pixel representation") == 1;
  if (elements.count(kRescaleSlope))
    s.slope = Numbers(text(kRescaleSlope), 1, file, "rescale slope (0028,1053)")[0];
  if (elements.count(kRescaleIntercept)) {
    s.intercept = Numbers(text(kRescaleIntercept), 1, file, "rescale intercept (0028,1052)")[0];
  }
  TROCAR_THROW_UNLESS(s.slope != 0.0, file << ": rescale slope (0028,1053) is 0");
  require(kPosition, "image position (patient)");
  require(kOrientation, "image orientation (patient)");
  require(kPixelSpacing, "pixel spacing");
  const auto p = Numbers(text(kPosition), 3, file, "image position (patient) (0020,0032)");
  s.position_mm = Eigen::Vector3d(p[0], p[1], p[2]);
  const auto o = Numbers(text(kOrientation), 6, file, "image orientation (patient) (0020,0037)");
  s.row_direction = Eigen::Vector3d(o[0], o[1], o[2]);
  s.column_direction = Eigen::Vector3d(o[3], o[4], o[5]);
  TROCAR_THROW_UNLESS(std::abs(s.row_direction.norm() - 1) < 1e-3 &&
                          std::abs(s.column_direction.norm() - 1) < 1e-3 &&
                          std::abs(s.row_direction.dot(s.column_direction)) < 1e-3,
                      file << ": image orientation (patient) (0020,0037) '" << text(kOrientation)
                           << "' is not two orthogonal unit vectors");
  s.row_direction.normalize();
  s.column_direction.normalize();
  const auto sp = Numbers(text(kPixelSpacing), 2, file, "pixel spacing (0028,0030)");
  s.spacing_mm = Eigen::Vector2d(sp[0], sp[1]);
  TROCAR_THROW_UNLESS((s.spacing_mm.array() > 0).all(), file << ": pixel spacing (0028,0030) '"
                                                             << text(kPixelSpacing)
                                                             << "' must be positive");
  if (elements.count(kInstanceNumber)) {
    const auto n = Numbers(text(kInstanceNumber), 1, file, "instance number (0020,0013)");
    s.instance = static_cast<int>(std::clamp(n[0], -1e9, 1e9));
  }
  const Range px = elements.at(kPixelData);
  const std::size_t needed = static_cast<std::size_t>(s.rows) * s.columns * (s.bits_allocated / 8);
  TROCAR_THROW_UNLESS(px.length >= needed, file << ": pixel data (7FE0,0010) has " << px.length
                                                << " bytes, expected " << needed << " for "
                                                << s.rows << " x " << s.columns << " pixels of "
                                                << s.bits_allocated << " bits");
  s.pixels = bytes.substr(px.offset, needed);
  return true;
}

void ConvertPixels(const Slice& s, float* out, long& bad) {
  const int bytes = s.bits_allocated / 8;
  const long n = static_cast<long>(s.rows) * s.columns;
  const auto* p = reinterpret_cast<const unsigned char*>(s.pixels.data());
  const std::uint32_t mask = s.bits_stored == 32 ? 0xFFFFFFFFu : ((1u << s.bits_stored) - 1u);
  const std::uint32_t sign = 1u << (s.bits_stored - 1);
  for (long v = 0; v < n; ++v, p += bytes) {
    std::uint32_t raw = 0;
    for (int b = 0; b < bytes; ++b) raw |= static_cast<std::uint32_t>(p[b]) << (8 * b);
    raw &= mask;
    double x = 0;
    if (s.is_signed && (raw & sign)) {
      x = static_cast<double>(static_cast<std::int64_t>(raw) -
                              (static_cast<std::int64_t>(mask) + 1));
    } else {
      x = static_cast<double>(raw);
    }
    x = s.slope * x + s.intercept;
    if (!std::isfinite(x)) ++bad;
    out[v] = static_cast<float>(x);
  }
}

// Decimal string of at most 16 characters (the DS limit), as precise as fits.
std::string DecimalString(double x) {
  if (std::abs(x) < 1e-12) x = 0.0;
  for (int precision = 15; precision > 1; --precision) {
    std::ostringstream s;
    s.precision(precision);
    s << x;
    if (s.str().size() <= 16) return s.str();
  }
  TROCAR_THROW("cannot write " << x << " as a DICOM decimal string");
}

std::uint64_t Fnv1a(std::uint64_t h, const void* data, std::size_t n) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) h = (h ^ p[i]) * 1099511628211ull;
  return h;
}

class Writer {
 public:
  explicit Writer(bool explicit_vr) : explicit_vr_(explicit_vr) {}
  void Element(std::uint16_t group, std::uint16_t element, const char* vr, std::string value) {
    if (value.size() % 2)
      value.push_back(std::string(vr) == "UI" || std::string(vr) == "OB" ? '\0' : ' ');
    U16(group);
    U16(element);
    if (explicit_vr_ || group == 0x0002) {
      out_.append(vr, 2);
      if (HasLongLength(vr)) {
        U16(0);
        U32(static_cast<std::uint32_t>(value.size()));
      } else {
        U16(static_cast<std::uint16_t>(value.size()));
      }
    } else {
      U32(static_cast<std::uint32_t>(value.size()));
    }
    out_ += value;
  }
  void Us(std::uint16_t group, std::uint16_t element, std::uint16_t v) {
    std::string b(2, '\0');
    b[0] = static_cast<char>(v & 0xFF);
    b[1] = static_cast<char>(v >> 8);
    Element(group, element, "US", b);
  }
  const std::string& bytes() const { return out_; }

 private:
  void U16(std::uint16_t v) {
    out_.push_back(static_cast<char>(v & 0xFF));
    out_.push_back(static_cast<char>(v >> 8));
  }
  void U32(std::uint32_t v) {
    U16(static_cast<std::uint16_t>(v & 0xFFFF));
    U16(static_cast<std::uint16_t>(v >> 16));
  }
  bool explicit_vr_;
  std::string out_;
};

}  // namespace

Volume LoadDicomSeries(const std::string& path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  const bool is_folder = fs::is_directory(path, ec);
  const std::string folder = is_folder ? path : ParentDirectory(path);
  TROCAR_THROW_UNLESS(is_folder || IsRegularFile(path), path << ": DICOM series not found");
  std::string wanted_series;
  if (!is_folder) {
    Slice chosen;
    TROCAR_THROW_UNLESS(ReadSlice(path, chosen), path << ": not a DICOM file (no DICM header)");
    wanted_series = chosen.series_uid;
  }
  std::vector<std::string> files;
  for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->is_regular_file(ec)) files.push_back(it->path().string());
  }
  TROCAR_THROW_UNLESS(!ec, folder << ": cannot list the DICOM folder: " << ec.message());
  std::sort(files.begin(), files.end());
  std::map<std::string, std::vector<Slice>> series;
  int skipped = 0;
  for (const auto& f : files) {
    Slice s;
    if (!ReadSlice(f, s)) {
      ++skipped;
      continue;
    }
    if (!wanted_series.empty() && s.series_uid != wanted_series) continue;
    series[s.series_uid].push_back(std::move(s));
  }
  TROCAR_THROW_UNLESS(!series.empty(), folder << ": no DICOM image slices among its "
                                              << files.size() << " files (" << skipped
                                              << " are not DICOM images)");
  if (series.size() > 1) {
    std::ostringstream list;
    for (const auto& [uid, slices] : series) {
      list << "\n  " << (uid.empty() ? "(no series UID)" : uid) << ": " << slices.size()
           << " slices, e.g. " << slices.front().file;
    }
    TROCAR_THROW(
        folder << ": holds " << series.size()
               << " series; give one of a series' files instead of the folder to choose it:"
               << list.str());
  }
  std::vector<Slice>& slices = series.begin()->second;
  TROCAR_THROW_UNLESS(slices.size() >= 2, folder << ": the series has one slice (" << slices[0].file
                                                 << "); a volume needs at least two");
  const Slice& first = slices.front();
  for (const Slice& s : slices) {
    TROCAR_THROW_UNLESS(s.rows == first.rows && s.columns == first.columns,
                        s.file << ": " << s.rows << " x " << s.columns << " pixels, but "
                               << first.file << " has " << first.rows << " x " << first.columns);
    TROCAR_THROW_UNLESS((s.row_direction - first.row_direction).norm() < 1e-4 &&
                            (s.column_direction - first.column_direction).norm() < 1e-4,
                        s.file << ": image orientation (0020,0037) differs from " << first.file
                               << "'s; the series is not one volume");
    TROCAR_THROW_UNLESS(
        (s.spacing_mm - first.spacing_mm).norm() < 1e-4 * first.spacing_mm.norm(),
        s.file << ": pixel spacing (0028,0030) differs from " << first.file << "'s");
  }
  // Slices sorted along the normal; the step between them is the third voxel axis (a gantry
  // tilt makes it oblique to the normal, which the volume's geometry keeps).
  const Eigen::Vector3d normal = first.row_direction.cross(first.column_direction);
  std::stable_sort(slices.begin(), slices.end(), [&](const Slice& a, const Slice& b) {
    return a.position_mm.dot(normal) < b.position_mm.dot(normal);
  });
  const int n = static_cast<int>(slices.size());
  std::vector<Eigen::Vector3d> steps;
  for (int k = 1; k < n; ++k) {
    const Eigen::Vector3d d = slices[k].position_mm - slices[k - 1].position_mm;
    TROCAR_THROW_UNLESS(d.dot(normal) > 1e-6,
                        slices[k].file << ": same position as " << slices[k - 1].file
                                       << " (a duplicate slice, or two series with one UID)");
    steps.push_back(d);
  }
  // The typical step (median along the normal) judges each gap, so that the message names the
  // gap that is off rather than its neighbours.
  std::vector<Eigen::Vector3d> sorted = steps;
  std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end(),
                   [&](const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
                     return a.dot(normal) < b.dot(normal);
                   });
  const Eigen::Vector3d typical_mm = sorted[sorted.size() / 2];
  for (int k = 1; k < n; ++k) {
    const Eigen::Vector3d& d = steps[k - 1];
    TROCAR_THROW_UNLESS((d - typical_mm).norm() <= 0.01 * typical_mm.norm() + 1e-3,
                        slices[k].file << ": " << d.norm() << " mm from the previous slice ("
                                       << slices[k - 1].file << ") where the series steps "
                                       << typical_mm.norm()
                                       << " mm: a missing slice or uneven spacing");
  }
  const Eigen::Vector3d step_mm =
      (slices.back().position_mm - slices.front().position_mm) / (n - 1);
  Volume v;
  v.size = Eigen::Vector3i(first.columns, first.rows, n);
  v.index_to_P.col(0) = first.row_direction * first.spacing_mm[1] * kMillimetre;
  v.index_to_P.col(1) = first.column_direction * first.spacing_mm[0] * kMillimetre;
  v.index_to_P.col(2) = step_mm * kMillimetre;
  v.origin_P = first.position_mm * kMillimetre;
  v.source = is_folder ? path : folder;
  const long per_slice = static_cast<long>(first.rows) * first.columns;
  v.values.resize(static_cast<std::size_t>(per_slice) * n);
  long bad = 0;
  for (int k = 0; k < n; ++k) {
    ConvertPixels(slices[k], v.values.data() + per_slice * k, bad);
    v.files.push_back(slices[k].file);
  }
  TROCAR_THROW_UNLESS(bad == 0, folder << ": " << bad << " voxels are not finite after rescaling");
  const bool ct = first.modality == "CT";
  v.hounsfield =
      ct || (!v.values.empty() && *std::min_element(v.values.begin(), v.values.end()) <= -500.0f &&
             (first.is_signed || first.intercept < 0));
  return v;
}

void WriteDicomSeries(const Volume& volume, const std::string& folder,
                      const DicomWriteOptions& options) {
  namespace fs = std::filesystem;
  TROCAR_THROW_UNLESS(
      static_cast<long>(volume.values.size()) == volume.voxel_count() && volume.voxel_count() > 0,
      folder << ": volume has " << volume.values.size() << " values for " << volume.voxel_count()
             << " voxels");
  TROCAR_THROW_UNLESS(volume.size.x() <= 65535 && volume.size.y() <= 65535,
                      folder << ": slices of " << volume.size.x() << " x " << volume.size.y()
                             << " pixels do not fit DICOM's 16-bit rows and columns");
  const Eigen::Vector3d c0 = volume.index_to_P.col(0), c1 = volume.index_to_P.col(1);
  TROCAR_THROW_UNLESS(
      std::abs(c0.normalized().dot(c1.normalized())) < 1e-6,
      folder << ": the volume's in-slice axes are not orthogonal; DICOM slices need them so");
  std::error_code ec;
  TROCAR_THROW_UNLESS(
      !fs::exists(folder, ec) || (fs::is_directory(folder, ec) && fs::is_empty(folder, ec)),
      folder << ": exists and is not an empty folder; the series needs a fresh one");
  // Values to 16-bit integers: as they are when they fit, else through a rescale.
  const auto [lo, hi] = std::minmax_element(volume.values.begin(), volume.values.end());
  const bool integral = *lo >= -32768.0f && *hi <= 32767.0f &&
                        std::all_of(volume.values.begin(), volume.values.end(),
                                    [](float x) { return x == std::round(x); });
  double slope = 1.0, intercept = 0.0;
  if (!integral) {
    slope = std::max(1e-12, (static_cast<double>(*hi) - *lo) / 65000.0);
    intercept = static_cast<double>(*lo) + 32500.0 * slope;
    // Written as DS: use the values the file will carry.
    slope = std::stod(DecimalString(slope));
    intercept = std::stod(DecimalString(intercept));
  }
  std::uint64_t h = 14695981039346656037ull;
  h = Fnv1a(h, volume.values.data(), volume.values.size() * sizeof(float));
  h = Fnv1a(h, volume.index_to_P.data(), 9 * sizeof(double));
  h = Fnv1a(h, volume.origin_P.data(), 3 * sizeof(double));
  h = Fnv1a(h, options.patient_name.data(), options.patient_name.size());
  const std::string study_uid = "2.25." + std::to_string(h >> 1);
  const std::string series_uid = "2.25." + std::to_string((h * 1099511628211ull) >> 1);
  auto ds_list = [](std::initializer_list<double> xs) {
    std::string s;
    for (double x : xs) s += (s.empty() ? "" : "\\") + DecimalString(x);
    return s;
  };
  const Eigen::Vector3d row = c0.normalized(), column = c1.normalized();
  const std::string ts = options.implicit_vr ? kImplicitLittle : kExplicitLittle;

  // Written into a fresh folder beside the target, then renamed: a failure leaves nothing behind
  // and never touches an existing folder.
  const fs::path target(folder);
  const fs::path temp = target.parent_path() / (target.filename().string() + ".partial-" + std::to_string(::getpid()));
  if (!target.parent_path().empty()) fs::create_directories(target.parent_path(), ec);
  TROCAR_THROW_UNLESS(fs::create_directory(temp, ec) && !ec,
                      temp.string() << ": cannot create the folder to write the series in"
                                    << (ec ? ": " + ec.message() : std::string(" (it exists)")));
  struct RemoveUnlessKept {
    fs::path path;
    bool keep = false;
    ~RemoveUnlessKept() {
      std::error_code ignored;
      if (!keep) fs::remove_all(path, ignored);
    }
  } cleanup{temp};
  const long per_slice = static_cast<long>(volume.size.x()) * volume.size.y();
  for (int k = 0; k < volume.size.z(); ++k) {
    const std::string instance_uid = series_uid + "." + std::to_string(k + 1);
    Writer meta(true);
    meta.Element(0x0002, 0x0001, "OB", std::string("\0\1", 2));
    meta.Element(0x0002, 0x0002, "UI", kCtImageStorage);
    meta.Element(0x0002, 0x0003, "UI", instance_uid);
    meta.Element(0x0002, 0x0010, "UI", ts);
    meta.Element(0x0002, 0x0012, "UI", "2.25.1147400720090");
    meta.Element(0x0002, 0x0013, "SH", "TROCAR");
    Writer group_length(true);
    std::string length(4, '\0');
    const auto n = static_cast<std::uint32_t>(meta.bytes().size());
    for (int b = 0; b < 4; ++b) length[b] = static_cast<char>((n >> (8 * b)) & 0xFF);
    group_length.Element(0x0002, 0x0000, "UL", length);

    Writer d(!options.implicit_vr);
    d.Element(0x0008, 0x0008, "CS", "DERIVED\\SECONDARY\\AXIAL");
    d.Element(0x0008, 0x0016, "UI", kCtImageStorage);
    d.Element(0x0008, 0x0018, "UI", instance_uid);
    d.Element(0x0008, 0x0060, "CS", volume.hounsfield ? "CT" : "OT");
    d.Element(0x0008, 0x103E, "LO", options.series_description);
    d.Element(0x0010, 0x0010, "PN", options.patient_name);
    d.Element(0x0010, 0x0020, "LO", options.patient_id);
    d.Element(0x0020, 0x000D, "UI", study_uid);
    d.Element(0x0020, 0x000E, "UI", series_uid);
    d.Element(0x0020, 0x0013, "IS", std::to_string(k + 1));
    const Eigen::Vector3d p_mm = volume.PatientPoint(0, 0, k) / kMillimetre;
    d.Element(0x0020, 0x0032, "DS", ds_list({p_mm.x(), p_mm.y(), p_mm.z()}));
    d.Element(0x0020, 0x0037, "DS",
              ds_list({row.x(), row.y(), row.z(), column.x(), column.y(), column.z()}));
    d.Us(0x0028, 0x0002, 1);
    d.Element(0x0028, 0x0004, "CS", "MONOCHROME2");
    d.Us(0x0028, 0x0010, static_cast<std::uint16_t>(volume.size.y()));
    d.Us(0x0028, 0x0011, static_cast<std::uint16_t>(volume.size.x()));
    d.Element(0x0028, 0x0030, "DS", ds_list({c1.norm() / kMillimetre, c0.norm() / kMillimetre}));
    d.Us(0x0028, 0x0100, 16);
    d.Us(0x0028, 0x0101, 16);
    d.Us(0x0028, 0x0102, 15);
    d.Us(0x0028, 0x0103, 1);
    d.Element(0x0028, 0x1052, "DS", DecimalString(intercept));
    d.Element(0x0028, 0x1053, "DS", DecimalString(slope));
    std::string pixels(2 * static_cast<std::size_t>(per_slice), '\0');
    for (long v = 0; v < per_slice; ++v) {
      const double x =
          (volume.values[static_cast<std::size_t>(per_slice * k + v)] - intercept) / slope;
      const auto q = static_cast<std::int16_t>(std::clamp(std::lround(x), -32768L, 32767L));
      const auto u = static_cast<std::uint16_t>(q);
      pixels[2 * v] = static_cast<char>(u & 0xFF);
      pixels[2 * v + 1] = static_cast<char>(u >> 8);
    }
    d.Element(0x7FE0, 0x0010, "OW", pixels);
    const std::string file =
        std::string(128, '\0') + "DICM" + group_length.bytes() + meta.bytes() + d.bytes();
    char name[32];
    std::snprintf(name, sizeof(name), "slice_%04d.dcm", k + 1);
    WriteFileAtomically((temp / name).string(), file);
  }
  fs::remove(target, ec);  // an empty folder may stand in the way of the rename
  fs::rename(temp, target, ec);
  TROCAR_THROW_UNLESS(!ec,
                      folder << ": cannot move the written series into place: " << ec.message());
}

}  // namespace trocar::patient
