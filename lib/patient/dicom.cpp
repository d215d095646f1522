// DICOM series. Reading goes through GDCM (Debian's libgdcm): it parses every encoding (implicit
// and explicit VR, little and big endian, deflated) and decodes every compressed pixel syntax it
// was built with (JPEG baseline/extended/lossless, JPEG-LS, JPEG 2000, RLE). What trocar adds on
// top is what GDCM leaves to the caller: the geometry is required, not defaulted (GDCM's image
// helper puts a missing origin at 0 and a missing spacing at 1 mm, silently), slices are sorted
// and their spacing checked, series are told apart, and every error names the file and element.
// Enhanced multi-frame CT is read frame by frame from its functional groups. The writer (classic
// CT slices, uncompressed little endian) stays hand-written: it is small, deterministic (UIDs
// derive from the content) and tested against VTK's independent reader.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <memory>
#include <set>
#include <sstream>

#include <unistd.h>
#include <zlib.h>

#include <gdcmDataSet.h>
#include <gdcmImage.h>
#include <gdcmImageReader.h>
#include <gdcmMediaStorage.h>
#include <gdcmSequenceOfItems.h>
#include <gdcmTrace.h>
#include <gdcmTransferSyntax.h>

#include "common/error.hpp"
#include "common/isolate.hpp"
#include "common/limits.hpp"
#include "common/file_util.hpp"
#include "patient/volume.hpp"

namespace trocar::patient {
namespace {

constexpr const char* kImplicitLittle = "1.2.840.10008.1.2";
constexpr const char* kExplicitLittle = "1.2.840.10008.1.2.1";
constexpr const char* kCtImageStorage = "1.2.840.10008.5.1.4.1.1.2";
/// A DICOM file larger than this is refused before it is read (a 512 x 512 enhanced CT of 2000
/// 16-bit frames is 1 GiB).
constexpr std::uintmax_t kMaxDicomFileBytes = std::uintmax_t{2} << 30;

std::string TagName(const gdcm::Tag& tag) {
  std::ostringstream s;
  s << "(" << std::hex << std::uppercase;
  s.width(4);
  s.fill('0');
  s << tag.GetGroup() << ",";
  s.width(4);
  s << tag.GetElement() << ")";
  return s.str();
}

// What a transfer syntax UID is called, for messages.
std::string TransferSyntaxName(const std::string& uid) {
  static const std::map<std::string, std::string> names = {
      {"1.2.840.10008.1.2", "Implicit VR Little Endian"},
      {"1.2.840.10008.1.2.1", "Explicit VR Little Endian"},
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
      {"1.2.840.10008.1.2.4.202", "HTJ2K Lossless RPCL"},
      {"1.2.840.10008.1.2.4.203", "HTJ2K"},
      {"1.2.840.10008.1.2.5", "RLE Lossless"},
  };
  const auto it = names.find(uid);
  return it == names.end() ? "unknown transfer syntax" : it->second;
}

// Value representations with a 4-byte length in explicit VR (for the writer).
bool HasLongLength(const char vr[2]) {
  static const char* kLong[] = {"OB", "OD", "OF", "OL", "OV", "OW", "SQ",
                                "UC", "UN", "UR", "UT", "SV", "UV"};
  for (const char* l : kLong) {
    if (vr[0] == l[0] && vr[1] == l[1]) return true;
  }
  return false;
}

// The value representations of DICOM (PS3.5 6.2).
bool KnownVr(const char vr[2]) {
  static const char* kAll[] = {"AE", "AS", "AT", "CS", "DA", "DS", "DT", "FL", "FD", "IS", "LO",
                               "LT", "OB", "OD", "OF", "OL", "OV", "OW", "PN", "SH", "SL", "SQ",
                               "SS", "ST", "SV", "TM", "UC", "UI", "UL", "UN", "UR", "US", "UT", "UV"};
  for (const char* k : kAll) {
    if (vr[0] == k[0] && vr[1] == k[1]) return true;
  }
  return false;
}

// GDCM reports through its own trace streams; trocar reports through its errors.
void QuietGdcm() {
  static const bool once = [] {
    gdcm::Trace::SetDebug(false);
    gdcm::Trace::SetWarning(false);
    gdcm::Trace::SetError(false);
    return true;
  }();
  (void)once;
}

struct Slice {
  std::string file;
  int frame = 0;    // within a multi-frame file
  int frames = 1;   // of that file
  std::string series_uid, modality, description;
  int rows = 0, columns = 0;
  bool is_signed = false;
  double slope = 1.0, intercept = 0.0;
  Eigen::Vector3d position_mm = Eigen::Vector3d::Zero();
  Eigen::Vector3d row_direction = Eigen::Vector3d::UnitX();     // along increasing column index
  Eigen::Vector3d column_direction = Eigen::Vector3d::UnitY();  // along increasing row index
  Eigen::Vector2d spacing_mm = Eigen::Vector2d::Ones();         // between rows, between columns
  int instance = 0;
  std::shared_ptr<const std::vector<float>> values;  // the file's frames, rescaled
  std::string where() const {
    return frames > 1 ? file + " (frame " + std::to_string(frame + 1) + ")" : file;
  }
};

// The text of a string element (trailing spaces and NULs cut), empty when absent.
std::string Text(const gdcm::DataSet& ds, const gdcm::Tag& tag) {
  if (!ds.FindDataElement(tag)) return {};
  const gdcm::DataElement& de = ds.GetDataElement(tag);
  const gdcm::ByteValue* bv = de.GetByteValue();
  if (bv == nullptr || bv->GetPointer() == nullptr) return {};
  std::string s(bv->GetPointer(), bv->GetLength());
  while (!s.empty() && (s.back() == ' ' || s.back() == '\0')) s.pop_back();
  const auto b = s.find_first_not_of(' ');
  return b == std::string::npos ? "" : s.substr(b);
}

// An element of a functional group item: the groups hold one macro sequence per attribute
// family (plane position, plane orientation, pixel measures, pixel value transformation), each
// with one item; the element is looked for in each.
std::string GroupText(const gdcm::DataSet* item, const gdcm::Tag& tag) {
  if (item == nullptr) return {};
  for (const gdcm::DataElement& de : item->GetDES()) {
    const gdcm::SmartPointer<gdcm::SequenceOfItems> sq = de.GetValueAsSQ();
    if (!sq || sq->GetNumberOfItems() == 0) continue;
    const std::string t = Text(sq->GetItem(1).GetNestedDataSet(), tag);
    if (!t.empty()) return t;
  }
  return {};
}

// Item `index` (0-based) of a sequence, or null.
const gdcm::DataSet* SequenceItem(const gdcm::DataSet& ds, const gdcm::Tag& tag, std::size_t index) {
  if (!ds.FindDataElement(tag)) return nullptr;
  const gdcm::SmartPointer<gdcm::SequenceOfItems> sq = ds.GetDataElement(tag).GetValueAsSQ();
  if (!sq || index >= sq->GetNumberOfItems()) return nullptr;
  return &sq->GetItem(index + 1).GetNestedDataSet();
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

// Whether a file looks like DICOM from its first bytes: the "DICM" magic after the 128-byte
// preamble, or a bare dataset (old ACR-NEMA style) starting with group 0008 or 0002. Other files
// (a README, a 3 GB video beside the slices) are skipped without being read.
enum class Sniff { kNotDicom, kDicom, kBare };
Sniff SniffFile(const std::string& file) {
  std::ifstream in(file, std::ios::binary);
  char head[132] = {};
  in.read(head, sizeof head);
  const std::streamsize n = in.gcount();
  if (n == 132 && std::memcmp(head + 128, "DICM", 4) == 0) return Sniff::kDicom;
  if (n >= 8 && (head[0] == 0x08 || head[0] == 0x02) && head[1] == 0x00) return Sniff::kBare;
  return Sniff::kNotDicom;
}

// ---- Structure check before GDCM ---------------------------------------------------------------
// Debian's GDCM is built with assertions on: some damaged files (a truncated header, a garbled
// length) abort the whole process inside gdcm::Reader instead of failing the read. So every
// file's element structure is walked here first, bounded, and only a file whose every element,
// sequence, item and pixel fragment lies inside it is handed to GDCM. This walk is the part of the
// former hand-written reader that stays (docs/decisions.md, "DICOM through GDCM").

constexpr std::uint32_t kUndefinedLength = 0xFFFFFFFFu;
constexpr int kMaxSequenceDepth = 16;
constexpr std::uint32_t Tag32(std::uint16_t group, std::uint16_t element) {
  return (static_cast<std::uint32_t>(group) << 16) | element;
}

std::string TagName32(std::uint32_t tag) {
  return TagName(gdcm::Tag(static_cast<std::uint16_t>(tag >> 16), static_cast<std::uint16_t>(tag & 0xFFFF)));
}

struct Range {
  std::size_t offset = 0;
  std::uint32_t length = 0;
};

// The value representation of the elements an image's geometry and pixels are read from, or
// nullptr for other elements.
const char* ImageElementVr(std::uint32_t tag) {
  static const std::map<std::uint32_t, const char*> kVr = {
      {Tag32(0x0008, 0x0016), "UI"}, {Tag32(0x0008, 0x0060), "CS"}, {Tag32(0x0018, 0x0050), "DS"},
      {Tag32(0x0018, 0x0088), "DS"}, {Tag32(0x0018, 0x1164), "DS"}, {Tag32(0x0020, 0x0032), "DS"},
      {Tag32(0x0020, 0x0037), "DS"}, {Tag32(0x0028, 0x0002), "US"}, {Tag32(0x0028, 0x0004), "CS"},
      {Tag32(0x0028, 0x0006), "US"}, {Tag32(0x0028, 0x0008), "IS"}, {Tag32(0x0028, 0x0009), "AT"},
      {Tag32(0x0028, 0x0010), "US"}, {Tag32(0x0028, 0x0011), "US"}, {Tag32(0x0028, 0x0030), "DS"},
      {Tag32(0x0028, 0x0100), "US"}, {Tag32(0x0028, 0x0101), "US"}, {Tag32(0x0028, 0x0102), "US"},
      {Tag32(0x0028, 0x0103), "US"}, {Tag32(0x0028, 0x1050), "DS"}, {Tag32(0x0028, 0x1051), "DS"},
      {Tag32(0x0028, 0x1052), "DS"}, {Tag32(0x0028, 0x1053), "DS"}, {Tag32(0x0028, 0x1054), "LO"},
      {Tag32(0x3004, 0x000C), "DS"}, {Tag32(0x7FE0, 0x0010), "OB/OW"},
      {Tag32(0x0028, 0x0034), "IS"}, {Tag32(0x0020, 0x000D), "UI"}, {Tag32(0x0020, 0x000E), "UI"},
      {Tag32(0x0008, 0x0018), "UI"}, {Tag32(0x0002, 0x0010), "UI"}, {Tag32(0x5200, 0x9229), "SQ"},
      {Tag32(0x5200, 0x9230), "SQ"}, {Tag32(0x0028, 0x9110), "SQ"}, {Tag32(0x0020, 0x9113), "SQ"},
      {Tag32(0x0020, 0x9116), "SQ"}};
  const auto it = kVr.find(tag);
  return it == kVr.end() ? nullptr : it->second;
}

class Walker {
 public:
  Walker(const std::string& bytes, const std::string& file, bool big_endian)
      : bytes_(bytes), file_(file), big_(big_endian) {}

  std::uint16_t U16(std::size_t at) const {
    Need(at, 2);
    return big_ ? static_cast<std::uint16_t>((Byte(at) << 8) | Byte(at + 1))
                : static_cast<std::uint16_t>(Byte(at) | (Byte(at + 1) << 8));
  }
  std::uint32_t U32(std::size_t at) const {
    const std::uint32_t a = U16(at), b = U16(at + 2);
    return big_ ? (a << 16) | b : a | (b << 16);
  }
  std::uint32_t Header(std::size_t& pos, bool explicit_vr, Range& value) const {
    const std::uint32_t tag = Tag32(U16(pos), U16(pos + 2));
    pos += 4;
    if ((tag >> 16) == 0xFFFE || !explicit_vr) {  // items and delimiters never carry a VR
      value.length = U32(pos);
      pos += 4;
    } else {
      Need(pos, 2);
      const char vr[2] = {bytes_[pos], bytes_[pos + 1]};
      TROCAR_THROW_UNLESS(KnownVr(vr), file_ << ": element " << TagName32(tag) << " at byte " << pos - 4
                                             << " has no known value representation (garbled or "
                                                "not explicit VR)");
      // GDCM's image helpers assert that these carry their dictionary VR (found by fuzzing:
      // pixel spacing written as US aborted the process).
      const char* expected = ImageElementVr(tag);
      const std::string allowed = expected == nullptr ? "" : expected;  // "OB/OW": either
      const bool fits = expected == nullptr || (vr[0] == 'U' && vr[1] == 'N') ||
                        (allowed.find(std::string(vr, 2)) != std::string::npos &&
                         allowed.find(std::string(vr, 2)) % 3 == 0);
      TROCAR_THROW_UNLESS(fits,
                          file_ << ": element " << TagName32(tag) << " at byte " << pos - 4
                                << " has value representation " << std::string(vr, 2)
                                << ", expected " << expected);
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
  // A value of undefined length: a sequence of items, or encapsulated pixel fragments.
  void SkipSequence(std::size_t& pos, bool explicit_vr, int depth) const {
    TROCAR_THROW_UNLESS(depth < kMaxSequenceDepth, file_ << ": sequences nested deeper than "
                                                         << kMaxSequenceDepth << " (garbled file)");
    for (;;) {
      Range item;
      const std::uint32_t tag = Header(pos, false, item);
      if (tag == Tag32(0xFFFE, 0xE0DD)) return;  // sequence delimiter
      TROCAR_THROW_UNLESS(tag == Tag32(0xFFFE, 0xE000), file_ << ": expected a sequence item at byte "
                                                              << pos - 8 << ", found " << TagName32(tag));
      if (item.length != kUndefinedLength) {
        Skip(pos, item.length);
        continue;
      }
      for (;;) {  // item of undefined length: elements up to the item delimiter
        Range value;
        const std::uint32_t inner = Header(pos, explicit_vr, value);
        if (inner == Tag32(0xFFFE, 0xE00D)) break;
        TROCAR_THROW_UNLESS((inner >> 16) != 0xFFFE, file_ << ": " << TagName32(inner) << " at byte "
                                                           << pos - 8 << " inside an item (garbled file)");
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
  bool Has(std::size_t at, std::size_t n) const { return at <= bytes_.size() && bytes_.size() - at >= n; }
  // The rest of the file from `pos` is zero padding.
  bool OnlyZerosFrom(std::size_t pos) const {
    return std::all_of(bytes_.begin() + static_cast<long>(std::min(pos, bytes_.size())), bytes_.end(),
                       [](char c) { return c == 0; });
  }

 private:
  unsigned Byte(std::size_t at) const { return static_cast<unsigned char>(bytes_[at]); }
  void Need(std::size_t at, std::size_t n) const {
    TROCAR_THROW_UNLESS(Has(at, n), file_ << ": truncated: needs " << n << " bytes at byte " << at
                                          << " but the data has " << bytes_.size());
  }
  const std::string& bytes_;
  const std::string& file_;
  bool big_;
};

// Raw deflate (a deflated transfer syntax's dataset), bounded.
std::string InflateRaw(const std::string& data, const std::string& file) {
  z_stream stream{};
  TROCAR_THROW_UNLESS(inflateInit2(&stream, -15) == Z_OK, file << ": cannot start decompression");
  std::string out;
  char buffer[1 << 16];
  stream.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
  stream.avail_in = static_cast<uInt>(std::min<std::size_t>(data.size(), 0xFFFFFFFFu));
  int status = Z_OK;
  while (status == Z_OK) {
    stream.next_out = reinterpret_cast<Bytef*>(buffer);
    stream.avail_out = sizeof buffer;
    status = inflate(&stream, Z_NO_FLUSH);
    out.append(buffer, sizeof buffer - stream.avail_out);
    if (out.size() > kMaxDicomFileBytes) status = Z_MEM_ERROR;
  }
  inflateEnd(&stream);
  TROCAR_THROW_UNLESS(status == Z_STREAM_END,
                      file << ": the deflated dataset does not inflate"
                           << (out.size() > kMaxDicomFileBytes ? " within the size limit" : " (damaged)"));
  return out;
}

// A UID value: digits and dots, at most 64 characters, padded with one NUL or space; empty is
// allowed (anonymised series blank them: totalseg-dicom-j2k).
void CheckUid(std::string value, const std::string& file, std::uint32_t tag) {
  while (!value.empty() && (value.back() == '\0' || value.back() == ' ')) value.pop_back();
  TROCAR_THROW_UNLESS(value.size() <= 64 &&
                          value.find_first_not_of("0123456789.") == std::string::npos,
                      file << ": " << TagName32(tag) << " is not a UID (digits and dots)");
}

// The file meta group (0002): its transfer syntax (implicit VR little endian for a bare dataset
// without one) and, in `pos`, where the dataset starts.
std::string ReadMetaGroup(const std::string& bytes, const std::string& file, Sniff sniff,
                          std::size_t* pos_out) {
  std::size_t pos = 0;
  std::string ts = "1.2.840.10008.1.2";  // a bare dataset: implicit VR little endian
  // A file meta group (0002) is read as explicit VR little endian: after the preamble and DICM,
  // or at the very start of a file without them (GDCM reads such a group the same way, and
  // asserts on one it cannot: found by fuzz_dicom).
  const bool bare_meta = sniff == Sniff::kBare && bytes.size() >= 2 && bytes[0] == 0x02 && bytes[1] == 0x00;
  if (sniff == Sniff::kDicom || bare_meta) {
    const Walker meta(bytes, file, false);
    pos = bare_meta ? 0 : 132;
    ts.clear();
    while (meta.Has(pos, 2) && meta.U16(pos) == 0x0002) {
      Range value;
      const std::uint32_t tag = meta.Header(pos, true, value);
      meta.Skip(pos, value.length);
      if (tag == Tag32(0x0002, 0x0010)) {
        ts = bytes.substr(value.offset, value.length);
        while (!ts.empty() && (ts.back() == ' ' || ts.back() == '\0')) ts.pop_back();
      }
      if (tag == Tag32(0x0002, 0x0002) || tag == Tag32(0x0002, 0x0003) || tag == Tag32(0x0002, 0x0010)) {
        CheckUid(bytes.substr(value.offset, value.length), file, tag);
      }
    }
    TROCAR_THROW_UNLESS(!ts.empty(), file << ": file meta information has no transfer syntax (0002,0010)");
  }
  *pos_out = pos;
  return ts;
}

// The dataset's top-level elements of defined length (sequences walked and skipped), and whether
// it holds pixel data.
struct TopLevel {
  std::map<std::uint32_t, Range> elements;
  bool has_pixels = false;
};

TopLevel WalkDataset(const Walker& walker, std::size_t at, bool explicit_vr,
                     const std::string& file) {
  TopLevel t;
  std::map<std::uint32_t, Range>& top = t.elements;
  std::set<std::uint32_t> seen;
  // GDCM asserts on a file that ends right after its meta information (found by fuzz_dicom).
  TROCAR_THROW_UNLESS(walker.Has(at, 8) && !walker.OnlyZerosFrom(at),
                      file << ": no dataset after the file meta information (truncated?)");
  while (walker.Has(at, 1)) {
    if (walker.OnlyZerosFrom(at)) break;  // trailing padding
    Range value;
    const std::uint32_t tag = walker.Header(at, explicit_vr, value);
    // Items and delimiters belong inside sequences: GDCM asserts on one at the top level (found
    // by fuzz_dicom).
    TROCAR_THROW_UNLESS((tag >> 16) != 0xFFFE, file << ": " << TagName32(tag) << " at byte " << at - 8
                                                   << " outside a sequence (garbled file)");
    if (tag == Tag32(0x7FE0, 0x0010)) t.has_pixels = true;
    // GDCM keeps the first of a repeated element, this walk would check the last: refuse both
    // (a repeated samples-per-pixel passed here and made GDCM assert; fuzz_dicom).
    TROCAR_THROW_UNLESS(seen.insert(tag).second, file << ": " << TagName32(tag) << " appears twice");
    if (value.length == kUndefinedLength) {
      walker.SkipSequence(at, explicit_vr, 0);
    } else {
      walker.Skip(at, value.length);
      top[tag] = value;
    }
  }
  return t;
}

// UIDs and the recognition code.
void CheckIdentity(const std::string& data, const std::map<std::uint32_t, Range>& top,
                   const std::string& file) {
  // UIDs are digits and dots (GDCM takes an unknown SOP class for ACR-NEMA and then asserts on
  // the recognition code; found by fuzz_dicom); the retired recognition code, when there, is
  // ACR-NEMA's.
  for (const std::uint32_t uid : {Tag32(0x0008, 0x0016), Tag32(0x0008, 0x0018), Tag32(0x0020, 0x000D),
                                  Tag32(0x0020, 0x000E)}) {
    if (const auto it = top.find(uid); it != top.end()) {
      CheckUid(data.substr(it->second.offset, it->second.length), file, uid);
    }
  }
  if (const auto it = top.find(Tag32(0x0008, 0x0010)); it != top.end()) {
    const std::string code = data.substr(it->second.offset, it->second.length);
    TROCAR_THROW_UNLESS(code.rfind("ACR-NEMA", 0) == 0 || code.rfind("ACRNEMA", 0) == 0 ||
                            code.rfind("MIPS 2.0", 0) == 0,
                        file << ": recognition code (0008,0010) is not ACR-NEMA's (garbled file)");
  }
}

// The image pixel module, which GDCM asserts on rather than checks: required fields present,
// values in range, pixel data as long as the header says.
void CheckPixelModule(const Walker& walker, const std::string& data, const TopLevel& t,
                      const std::string& file) {
  const std::map<std::uint32_t, Range>& top = t.elements;
  // An image's pixel description is required, not defaulted: GDCM fills gaps with defaults that
  // can contradict each other and then asserts (bits stored above bits allocated; fuzz_dicom).
  if (t.has_pixels) {
    for (const auto& [element, name] : {std::make_pair(0x0010, "rows"), std::make_pair(0x0011, "columns"),
                                        std::make_pair(0x0100, "bits allocated"),
                                        std::make_pair(0x0101, "bits stored")}) {
      TROCAR_THROW_UNLESS(top.count(Tag32(0x0028, static_cast<std::uint16_t>(element))),
                          file << ": an image without " << name << " "
                               << TagName32(Tag32(0x0028, static_cast<std::uint16_t>(element))));
    }
  }
  auto us = [&](std::uint16_t element, const char* name, int fallback) {
    const auto it = top.find(Tag32(0x0028, element));
    if (it == top.end()) return fallback;
    TROCAR_THROW_UNLESS(it->second.length == 2, file << ": " << name << " " << TagName32(it->first)
                                                     << " has " << it->second.length
                                                     << " bytes, expected 2 (US)");
    return static_cast<int>(walker.U16(it->second.offset));
  };
  const int samples = us(0x0002, "samples per pixel", 1);
  TROCAR_THROW_UNLESS(samples == 1, file << ": samples per pixel (0028,0002) is " << samples
                                         << ", expected 1 (a grey-level CT)");
  const int allocated = us(0x0100, "bits allocated", 16);
  TROCAR_THROW_UNLESS(allocated == 8 || allocated == 16 || allocated == 32,
                      file << ": bits allocated (0028,0100) is " << allocated << ", expected 8, 16 or 32");
  const int stored = us(0x0101, "bits stored", allocated);
  TROCAR_THROW_UNLESS(stored >= 1 && stored <= allocated, file << ": bits stored (0028,0101) is " << stored
                                                                << ", expected 1 to " << allocated);
  const int high = us(0x0102, "high bit", stored - 1);
  TROCAR_THROW_UNLESS(high == stored - 1, file << ": high bit (0028,0102) is " << high << ", expected "
                                                << stored - 1 << " (bits stored - 1)");
  const int representation = us(0x0103, "pixel representation", 0);
  TROCAR_THROW_UNLESS(representation == 0 || representation == 1,
                      file << ": pixel representation (0028,0103) is " << representation
                           << ", expected 0 (unsigned) or 1 (signed)");
  const int planar = us(0x0006, "planar configuration", 0);
  TROCAR_THROW_UNLESS(planar == 0 || planar == 1, file << ": planar configuration (0028,0006) is " << planar);
  const int rows = us(0x0010, "rows", 1), columns = us(0x0011, "columns", 1);
  TROCAR_THROW_UNLESS(rows > 0 && columns > 0, file << ": image is " << rows << " x " << columns << " pixels");
  auto text = [&](std::uint16_t group, std::uint16_t element) {
    const auto it = top.find(Tag32(group, element));
    if (it == top.end()) return std::string();
    std::string t = data.substr(it->second.offset, it->second.length);
    while (!t.empty() && (t.back() == ' ' || t.back() == '\0')) t.pop_back();
    return t;
  };
  const std::string photometric = text(0x0028, 0x0004);
  TROCAR_THROW_UNLESS(photometric.empty() || photometric == "MONOCHROME2" || photometric == "MONOCHROME1",
                      file << ": photometric interpretation (0028,0004) '" << photometric
                           << "', expected MONOCHROME2");
  // Rescale: GDCM asserts on a zero slope, or on an intercept without a slope (which it takes as
  // 0; both found by fuzz_dicom): they come together, as numbers.
  TROCAR_THROW_UNLESS(top.count(Tag32(0x0028, 0x1052)) == top.count(Tag32(0x0028, 0x1053)),
                      file << ": rescale intercept (0028,1052) and rescale slope (0028,1053) must "
                              "be given together");
  for (const auto& [element, name] : {std::make_pair(0x1053, "rescale slope"),
                                      std::make_pair(0x1052, "rescale intercept")}) {
    const std::string value = text(0x0028, static_cast<std::uint16_t>(element));
    if (value.empty()) continue;
    const std::string first = value.substr(0, value.find('\\'));
    char* end = nullptr;
    const double x = std::strtod(first.c_str(), &end);
    while (end != nullptr && *end == ' ') ++end;
    TROCAR_THROW_UNLESS(end != first.c_str() && end != nullptr && *end == '\0' && std::isfinite(x) &&
                            (element != 0x1053 || x != 0.0),
                        file << ": " << name << " " << TagName32(Tag32(0x0028, static_cast<std::uint16_t>(element)))
                             << " is '" << value << "', expected a finite number"
                             << (element == 0x1053 ? " other than 0" : ""));
  }
  long frame_count = 1;
  if (const std::string frames = text(0x0028, 0x0008); !frames.empty()) {
    char* end = nullptr;
    const long n = std::strtol(frames.c_str(), &end, 10);
    TROCAR_THROW_UNLESS(end && *end == '\0' && n >= 1 && n <= 65535,
                        file << ": number of frames (0028,0008) '" << frames << "', expected 1 to 65535");
    frame_count = n;
  }
  // Native (not encapsulated) pixel data holds every pixel the header describes: GDCM's raw codec
  // copies that many bytes whatever the element's length (a heap over-read; fuzz_dicom).
  if (const auto it = top.find(Tag32(0x7FE0, 0x0010)); it != top.end()) {
    const std::uint64_t needed = static_cast<std::uint64_t>(rows) * columns * (allocated / 8) *
                                 samples * static_cast<std::uint64_t>(frame_count);
    TROCAR_THROW_UNLESS(it->second.length >= needed,
                        file << ": pixel data (7FE0,0010) has " << it->second.length << " bytes, "
                             << rows << " x " << columns << " pixels of " << allocated
                             << " bits x " << frame_count << " frame(s) need " << needed);
  }
}

// Walks every element of a file (meta group, then the dataset in its transfer syntax's encoding).
// @throws trocar::Error naming the file and where the structure breaks.
void CheckStructure(const std::string& bytes, const std::string& file, Sniff sniff) {
  std::size_t pos = 0;
  const std::string ts = ReadMetaGroup(bytes, file, sniff, &pos);
  std::string inflated;
  const bool deflated = ts == "1.2.840.10008.1.2.1.99";
  if (deflated) inflated = InflateRaw(bytes.substr(pos), file);
  const std::string& data = deflated ? inflated : bytes;
  const std::size_t at = deflated ? 0 : pos;
  const Walker walker(data, file, ts == "1.2.840.10008.1.2.2");
  const bool explicit_vr = ts != "1.2.840.10008.1.2";
  const TopLevel top = WalkDataset(walker, at, explicit_vr, file);
  CheckIdentity(data, top.elements, file);
  CheckPixelModule(walker, data, top, file);
}

bool DecodeIsolated(IsolatedWorker* decoder, const std::string& bytes_read,
                    const std::string& file, Sniff sniff, std::vector<Slice>* out);

// Reads one file into its slices (one, or one per frame): sniffed, size-checked and
// structure-walked here, decoded by GDCM in the decoder process. Returns false when it is not a
// DICOM image (not DICOM, or a DICOMDIR, a report, a presentation state), so that folders may
// hold such files beside the slices.
bool ReadFile(const std::string& file, IsolatedWorker* decoder, std::vector<Slice>* out) {
  QuietGdcm();
  const Sniff sniff = SniffFile(file);
  if (sniff == Sniff::kNotDicom) return false;
  std::error_code ec;
  const std::uintmax_t bytes = std::filesystem::file_size(file, ec);
  TROCAR_THROW_UNLESS(!ec, file << ": cannot read its size: " << ec.message());
  TROCAR_THROW_UNLESS(bytes <= kMaxDicomFileBytes,
                      file << ": " << bytes << " bytes, more than the " << kMaxDicomFileBytes
                           << " a DICOM image file may have here");
  const std::string bytes_read = ReadBinaryFile(file);
  CheckStructure(bytes_read, file, sniff);
  return DecodeIsolated(decoder, bytes_read, file, sniff, out);
}

// A file's transfer syntax in words, for messages: "transfer syntax UID (name)".
std::string TransferSyntaxText(const gdcm::File& f) {
  const std::string ts_uid =
      f.GetHeader().GetDataSetTransferSyntax().IsValid()
          ? gdcm::TransferSyntax::GetTSString(f.GetHeader().GetDataSetTransferSyntax())
          : Text(f.GetHeader(), gdcm::Tag(0x0002, 0x0010));
  return "transfer syntax " + (ts_uid.empty() ? std::string("(none)") : ts_uid) + " (" +
         TransferSyntaxName(ts_uid) + ")";
}

// Whether GDCM's reading gave an image to decode: false for what is skipped (a readable non-image
// object, a bare file that is not DICOM, a file without pixel data); throws for a file that
// looks like an image and fails.
bool IsImageToDecode(bool read, const gdcm::File& f, const std::string& file, Sniff sniff) {
  const gdcm::DataSet& ds = f.GetDataSet();
  const gdcm::Tag kPixelData(0x7fe0, 0x0010), kRows(0x0028, 0x0010);
  if (!read) {
    gdcm::MediaStorage ms;
    ms.SetFromFile(f);
    const bool image_like = ds.FindDataElement(kPixelData) || ds.FindDataElement(kRows);
    // A readable non-image object (DICOMDIR, report) and a bare file that is not DICOM are
    // skipped; a file that looks like an image and fails is an error.
    if (!image_like && (sniff == Sniff::kBare || (ms != gdcm::MediaStorage::MS_END && !gdcm::MediaStorage::IsImage(ms))))
      return false;
    TROCAR_THROW_UNLESS(image_like || sniff == Sniff::kDicom, file << ": not DICOM");
    TROCAR_THROW(file << ": GDCM cannot read it (" << TransferSyntaxText(f)
                      << "): truncated, damaged, or an encoding GDCM does not know");
  }
  if (!ds.FindDataElement(kPixelData)) {
    TROCAR_THROW_UNLESS(!ds.FindDataElement(kRows),
                        file << ": image with no pixel data (7FE0,0010) (truncated?)");
    return false;
  }
  return true;
}

// The pixel format a grey-level CT has: one sample, monochrome, 8, 16 or 32 bits allocated.
void CheckPixelFormat(const gdcm::Image& image, const std::string& file) {
  const gdcm::PixelFormat& pf = image.GetPixelFormat();
  TROCAR_THROW_UNLESS(pf.GetSamplesPerPixel() == 1,
                      file << ": samples per pixel (0028,0002) is " << pf.GetSamplesPerPixel()
                           << ", expected 1 (a grey-level CT)");
  const auto pi = image.GetPhotometricInterpretation();
  TROCAR_THROW_UNLESS(pi == gdcm::PhotometricInterpretation::MONOCHROME2 ||
                          pi == gdcm::PhotometricInterpretation::MONOCHROME1,
                      file << ": photometric interpretation (0028,0004) '"
                           << (pi.GetString() ? pi.GetString() : "?") << "', expected MONOCHROME2");
  const int bits_allocated = pf.GetBitsAllocated(), bits_stored = pf.GetBitsStored();
  TROCAR_THROW_UNLESS(bits_allocated == 8 || bits_allocated == 16 || bits_allocated == 32,
                      file << ": bits allocated (0028,0100) is " << bits_allocated
                           << ", expected 8, 16 or 32");
  TROCAR_THROW_UNLESS(bits_stored >= 1 && bits_stored <= bits_allocated,
                      file << ": bits stored (0028,0101) is " << bits_stored << ", expected 1 to "
                           << bits_allocated);
}

// A frame's fields: its own functional group first, then the shared functional groups, then the
// top level (classic images). A multi-frame file may also carry a top-level value (e.g. the first
// frame's position), which must not stand for every frame.
class FrameFields {
 public:
  FrameFields(const gdcm::DataSet& ds, const std::string& file, int frames)
      : ds_(ds),
        file_(file),
        frames_(frames),
        shared_(SequenceItem(ds, gdcm::Tag(0x5200, 0x9229), 0)) {}
  /// The frame's own functional group's value only.
  std::string Own(const gdcm::Tag& tag, int frame) const {
    return GroupText(SequenceItem(ds_, gdcm::Tag(0x5200, 0x9230), frame), tag);
  }
  std::string Field(const gdcm::Tag& tag, int frame) const {
    std::string t = Own(tag, frame);
    if (t.empty()) t = GroupText(shared_, tag);
    if (t.empty()) t = Text(ds_, tag);
    return t;
  }
  std::string Require(const gdcm::Tag& tag, int frame, const char* name) const {
    const std::string t = Field(tag, frame);
    TROCAR_THROW_UNLESS(
        !t.empty(),
        file_ << ": missing " << name << " " << TagName(tag)
              << (frames_ > 1 ? " for frame " + std::to_string(frame + 1) : std::string()));
    return t;
  }

 private:
  const gdcm::DataSet& ds_;
  const std::string& file_;
  int frames_;
  const gdcm::DataSet* shared_;
};

const gdcm::Tag kImagePosition(0x0020, 0x0032), kImageOrientation(0x0020, 0x0037),
    kPixelSpacing(0x0028, 0x0030), kRescaleSlope(0x0028, 0x1053), kRescaleIntercept(0x0028, 0x1052);

// The slice's identity (size, series, modality, instance) from the image and its data set.
Slice DescribeSlice(const gdcm::Image& image, const gdcm::DataSet& ds, const std::string& file) {
  const unsigned* dims = image.GetDimensions();
  Slice s;
  s.file = file;
  s.columns = static_cast<int>(dims[0]);
  s.rows = static_cast<int>(dims[1]);
  s.frames = image.GetNumberOfDimensions() >= 3 ? static_cast<int>(dims[2]) : 1;
  TROCAR_THROW_UNLESS(s.rows > 0 && s.columns > 0 && s.frames > 0 && s.rows <= 65535 &&
                          s.columns <= 65535,
                      file << ": image is " << s.rows << " x " << s.columns << " pixels, "
                           << s.frames << " frame(s)");
  s.is_signed = image.GetPixelFormat().GetPixelRepresentation() == 1;
  s.series_uid = Text(ds, gdcm::Tag(0x0020, 0x000e));
  s.modality = Text(ds, gdcm::Tag(0x0008, 0x0060));
  s.description = Text(ds, gdcm::Tag(0x0008, 0x103e));
  if (const std::string n = Text(ds, gdcm::Tag(0x0020, 0x0013)); !n.empty()) {
    s.instance = static_cast<int>(std::clamp(Numbers(n, 1, file, "instance number (0020,0013)")[0], -1e9, 1e9));
  }
  return s;
}

// The rows' and columns' directions and the pixel spacing (the first frame's).
void ReadPlaneGeometry(const FrameFields& fields, const std::string& file, Slice* s) {
  const std::string orientation =
      fields.Require(kImageOrientation, 0, "image orientation (patient)");
  const auto o = Numbers(orientation, 6, file, "image orientation (patient) (0020,0037)");
  s->row_direction = Eigen::Vector3d(o[0], o[1], o[2]);
  s->column_direction = Eigen::Vector3d(o[3], o[4], o[5]);
  TROCAR_THROW_UNLESS(std::abs(s->row_direction.norm() - 1) < 1e-3 &&
                          std::abs(s->column_direction.norm() - 1) < 1e-3 &&
                          std::abs(s->row_direction.dot(s->column_direction)) < 1e-3,
                      file << ": image orientation (patient) (0020,0037) '" << orientation
                           << "' is not two orthogonal unit vectors");
  s->row_direction.normalize();
  s->column_direction.normalize();
  const std::string spacing = fields.Require(kPixelSpacing, 0, "pixel spacing");
  const auto sp = Numbers(spacing, 2, file, "pixel spacing (0028,0030)");
  s->spacing_mm = Eigen::Vector2d(sp[0], sp[1]);
  TROCAR_THROW_UNLESS((s->spacing_mm.array() > 0).all(),
                      file << ": pixel spacing (0028,0030) '" << spacing << "' must be positive");
}

// Pixels, decoded by GDCM whatever the transfer syntax, and rescaled per frame.
void DecodePixels(const gdcm::Image& image, const FrameFields& fields, const std::string& file,
                  const std::string& ts_text, Slice* s) {
  const gdcm::PixelFormat& pf = image.GetPixelFormat();
  const int bits_allocated = pf.GetBitsAllocated(), bits_stored = pf.GetBitsStored();
  const std::size_t bytes_per = static_cast<std::size_t>(bits_allocated / 8);
  const std::size_t per_frame = static_cast<std::size_t>(s->rows) * s->columns;
  const std::size_t expected = per_frame * s->frames * bytes_per;
  TROCAR_THROW_UNLESS(image.GetBufferLength() == expected,
                      file << ": GDCM gives " << image.GetBufferLength()
                           << " bytes of pixels, expected " << expected << " for " << s->frames
                           << " frame(s) of " << s->rows << " x " << s->columns << " pixels of "
                           << bits_allocated << " bits");
  std::vector<char> raw(expected);
  TROCAR_THROW_UNLESS(
      image.GetBuffer(raw.data()),
      file << ": " << ts_text
           << ": GDCM cannot decode its pixel data (damaged, or a codec this GDCM was built "
              "without). Convert the series to uncompressed DICOM with a tool that decodes it "
              "(e.g. dcmtk's dcmdjpeg, dcmdjpls or dcmdrle), or export it as NIfTI");
  auto values = std::make_shared<std::vector<float>>(per_frame * s->frames);
  const std::uint32_t mask = bits_stored == 32 ? 0xFFFFFFFFu : ((1u << bits_stored) - 1u);
  const std::uint32_t sign = 1u << (bits_stored - 1);
  long bad = 0;
  for (int frame = 0; frame < s->frames; ++frame) {
    double slope = 1.0, intercept = 0.0;
    if (const std::string t = fields.Field(kRescaleSlope, frame); !t.empty())
      slope = Numbers(t, 1, file, "rescale slope (0028,1053)")[0];
    if (const std::string t = fields.Field(kRescaleIntercept, frame); !t.empty())
      intercept = Numbers(t, 1, file, "rescale intercept (0028,1052)")[0];
    TROCAR_THROW_UNLESS(slope != 0.0, file << ": rescale slope (0028,1053) is 0");
    if (frame == 0) {
      s->slope = slope;
      s->intercept = intercept;
    }
    const auto* p = reinterpret_cast<const unsigned char*>(raw.data()) + per_frame * frame * bytes_per;
    float* v = values->data() + per_frame * frame;
    for (std::size_t n = 0; n < per_frame; ++n, p += bytes_per) {
      std::uint32_t word = 0;  // GDCM hands the buffer over in the machine's (little-endian) order
      for (std::size_t b = 0; b < bytes_per; ++b) word |= static_cast<std::uint32_t>(p[b]) << (8 * b);
      word &= mask;
      const double x = s->is_signed && (word & sign)
                           ? static_cast<double>(static_cast<std::int64_t>(word) -
                                                 (static_cast<std::int64_t>(mask) + 1))
                           : static_cast<double>(word);
      const double y = slope * x + intercept;
      if (!std::isfinite(y)) ++bad;
      v[n] = static_cast<float>(y);
    }
  }
  TROCAR_THROW_UNLESS(bad == 0, file << ": " << bad << " voxels are not finite after rescaling");
  s->values = values;
}

// One slice per frame, each at its own position.
void SplitFrames(const Slice& s, const FrameFields& fields, const gdcm::DataSet& ds,
                 const std::string& file, std::vector<Slice>* out) {
  const Eigen::Vector3d normal = s.row_direction.cross(s.column_direction);
  double between = 0.0;
  if (s.frames > 1 && fields.Own(kImagePosition, 1).empty()) {
    // A multi-frame image without per-frame positions: frames evenly spaced along the normal.
    const std::string t = Text(ds, gdcm::Tag(0x0018, 0x0088));
    TROCAR_THROW_UNLESS(!t.empty(), file << ": " << s.frames
                                         << " frames but neither per-frame positions (plane "
                                            "position sequence (0020,9113)) nor spacing between "
                                            "slices (0018,0088)");
    between = Numbers(t, 1, file, "spacing between slices (0018,0088)")[0];
  }
  const auto p0 = Numbers(fields.Require(kImagePosition, 0, "image position (patient)"), 3, file,
                          "image position (patient) (0020,0032)");
  for (int frame = 0; frame < s.frames; ++frame) {
    Slice fs = s;
    fs.frame = frame;
    if (frame == 0 || between != 0.0) {
      fs.position_mm = Eigen::Vector3d(p0[0], p0[1], p0[2]) + frame * between * normal;
    } else {
      const auto p = Numbers(fields.Require(kImagePosition, frame, "image position (patient)"), 3,
                             file, "image position (patient) (0020,0032)");
      fs.position_mm = Eigen::Vector3d(p[0], p[1], p[2]);
    }
    out->push_back(std::move(fs));
  }
}

// GDCM's part of reading one file: parse `bytes_read`, decode the pixels, fill the slices.
bool DecodeWithGdcm(const std::string& bytes_read, const std::string& file, Sniff sniff,
                    std::vector<Slice>* out) {
  std::istringstream stream(bytes_read);
  gdcm::ImageReader reader;
  reader.SetStream(stream);
  const bool read = reader.Read();
  const gdcm::File& f = reader.GetFile();
  if (!IsImageToDecode(read, f, file, sniff)) return false;
  const gdcm::DataSet& ds = f.GetDataSet();
  const gdcm::Image& image = reader.GetImage();
  CheckPixelFormat(image, file);
  Slice s = DescribeSlice(image, ds, file);
  const FrameFields fields(ds, file, s.frames);
  ReadPlaneGeometry(fields, file, &s);
  DecodePixels(image, fields, file, TransferSyntaxText(f), &s);
  SplitFrames(s, fields, ds, file, out);
  return true;
}

// The slices of one file, sent from the decoder process to trocar: plain bytes in this machine's
// order (both ends are this program). Every frame of a file shares one array of values.
class SliceWriter {
 public:
  explicit SliceWriter(std::string* out) : out_(out) {}
  template <typename T>
  void Put(const T& v) {
    out_->append(reinterpret_cast<const char*>(&v), sizeof v);
  }
  void Put(const std::string& s) {
    Put<std::uint64_t>(s.size());
    out_->append(s);
  }
  void Put(const Eigen::Vector3d& v) { out_->append(reinterpret_cast<const char*>(v.data()), sizeof(double) * 3); }
  void Put(const Eigen::Vector2d& v) { out_->append(reinterpret_cast<const char*>(v.data()), sizeof(double) * 2); }
  void Put(const bool& b) { Put<std::uint8_t>(b ? 1 : 0); }
  template <typename T>
  void operator()(const T& v) {  // for SliceFields
    Put(v);
  }

 private:
  std::string* out_;
};

class SliceReader {
 public:
  SliceReader(const std::string& in, const std::string& file) : in_(in), file_(file) {}
  void Raw(void* to, std::size_t n) {
    TROCAR_THROW_UNLESS(n <= in_.size() - at_, file_ << ": the DICOM decoder's answer is truncated");
    if (n == 0) return;  // `to` may be the null data of an empty vector
    std::memcpy(to, in_.data() + at_, n);
    at_ += n;
  }
  template <typename T>
  T Get() {
    T v;
    Raw(&v, sizeof v);
    return v;
  }
  std::string String() {
    const auto n = Get<std::uint64_t>();
    TROCAR_THROW_UNLESS(n <= in_.size() - at_, file_ << ": the DICOM decoder's answer is truncated");
    std::string s = in_.substr(at_, n);
    at_ += n;
    return s;
  }
  bool AtEnd() const { return at_ == in_.size(); }
  // For SliceFields.
  void operator()(std::string& v) { v = String(); }
  void operator()(bool& v) { v = Get<std::uint8_t>() != 0; }
  void operator()(Eigen::Vector3d& v) { Raw(v.data(), sizeof(double) * 3); }
  void operator()(Eigen::Vector2d& v) { Raw(v.data(), sizeof(double) * 2); }
  void operator()(int& v) { v = Get<int>(); }
  void operator()(double& v) { v = Get<double>(); }

 private:
  const std::string& in_;
  const std::string& file_;
  std::size_t at_ = 0;
};

// The fields of a slice that cross from the decoder process, listed once for both directions
// (`io` is a SliceWriter or a SliceReader). The file name and the values travel separately.
template <typename Io, typename S>
void SliceFields(Io& io, S& s) {
  io(s.frame);
  io(s.frames);
  io(s.series_uid);
  io(s.modality);
  io(s.description);
  io(s.rows);
  io(s.columns);
  io(s.is_signed);
  io(s.slope);
  io(s.intercept);
  io(s.position_mm);
  io(s.row_direction);
  io(s.column_direction);
  io(s.spacing_mm);
  io(s.instance);
}

// The decoder process's side of one request (sniff, file name, bytes): GDCM parses and decodes,
// the slices go back as bytes.
void DecodeRequest(const std::string& request, std::string* o) {
  const std::string what = "the decoder's request";  // SliceReader keeps a reference
  SliceReader in(request, what);
  const auto sniff = static_cast<Sniff>(in.Get<std::uint8_t>());
  const std::string file = in.String();
  const std::string bytes_read = in.String();
  std::vector<Slice> slices;
  const bool image = DecodeWithGdcm(bytes_read, file, sniff, &slices);
  SliceWriter w(o);
  w.Put<std::uint8_t>(image ? 1 : 0);
  w.Put<std::uint64_t>(slices.size());
  for (const Slice& s : slices) SliceFields(w, s);
  const std::vector<float> none;
  const std::vector<float>& values = slices.empty() || !slices.front().values ? none : *slices.front().values;
  w.Put<std::uint64_t>(values.size());
  o->append(reinterpret_cast<const char*>(values.data()), values.size() * sizeof(float));
}

// The decoder process for one series (lib/common/isolate): Debian's GDCM asserts (aborts) on
// many damaged files that trocar's structure walk cannot all foresee; an abort there is an error
// naming the file, not the end of trocar. One process serves the whole series.
IsolateOptions DecoderOptions() {
  IsolateOptions options;
  // The answer: 4 bytes a voxel (float) plus the header of each frame.
  options.max_output_bytes = Limits().max_voxels * sizeof(float) + (std::uint64_t{1} << 20);
  return options;
}

// Decodes one file in the decoder process.
bool DecodeIsolated(IsolatedWorker* decoder, const std::string& bytes_read,
                    const std::string& file, Sniff sniff, std::vector<Slice>* out) {
  std::string request;
  SliceWriter req(&request);
  req.Put<std::uint8_t>(static_cast<std::uint8_t>(sniff));
  req.Put(file);
  req.Put(bytes_read);
  const double timeout_s = 60.0 + static_cast<double>(bytes_read.size()) / 1e6;  // 1 s a MB more
  const std::string answer = decoder->Call(file, request, timeout_s);

  SliceReader r(answer, file);
  const bool image = r.Get<std::uint8_t>() != 0;
  const auto count = r.Get<std::uint64_t>();
  TROCAR_THROW_UNLESS(count <= answer.size(), file << ": the DICOM decoder's answer is damaged");
  std::vector<Slice> slices(count);
  std::uint64_t voxels = 0;
  for (Slice& s : slices) {
    s.file = file;
    SliceFields(r, s);
    TROCAR_THROW_UNLESS(s.rows > 0 && s.columns > 0 && s.rows <= 65535 && s.columns <= 65535,
                        file << ": the DICOM decoder's answer is damaged (" << s.rows << " x "
                             << s.columns << " pixels)");
    voxels += static_cast<std::uint64_t>(s.rows) * static_cast<std::uint64_t>(s.columns);
  }
  const auto n = r.Get<std::uint64_t>();
  TROCAR_THROW_UNLESS(n == voxels && n * sizeof(float) <= answer.size(),
                      file << ": the DICOM decoder's answer is damaged (" << n << " values for "
                           << voxels << " pixels)");
  auto values = std::make_shared<std::vector<float>>(n);
  r.Raw(values->data(), n * sizeof(float));
  TROCAR_THROW_UNLESS(r.AtEnd(), file << ": the DICOM decoder's answer is damaged (trailing bytes)");
  for (Slice& s : slices) {
    s.values = values;
    out->push_back(std::move(s));
  }
  return image;
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
  IsolatedWorker decoder(DecodeRequest, DecoderOptions());
  std::string wanted_series;
  std::vector<std::string> files;
  if (!is_folder) {
    std::vector<Slice> chosen;
    TROCAR_THROW_UNLESS(ReadFile(path, &decoder, &chosen), path << ": not a DICOM image file");
    wanted_series = chosen.front().series_uid;
    // A multi-frame file is a whole series by itself.
    if (chosen.size() > 1) files.push_back(path);
  }
  if (files.empty()) {
    for (fs::directory_iterator it(folder, ec), end; !ec && it != end; it.increment(ec)) {
      if (it->is_regular_file(ec)) files.push_back(it->path().string());
    }
    TROCAR_THROW_UNLESS(!ec, folder << ": cannot list the DICOM folder: " << ec.message());
  }
  std::sort(files.begin(), files.end());
  std::map<std::string, std::vector<Slice>> series;
  int skipped = 0;
  for (const auto& f : files) {
    std::vector<Slice> slices;
    if (!ReadFile(f, &decoder, &slices)) {
      ++skipped;
      continue;
    }
    if (!wanted_series.empty() && slices.front().series_uid != wanted_series) continue;
    auto& list = series[slices.front().series_uid];
    for (auto& s : slices) list.push_back(std::move(s));
  }
  TROCAR_THROW_UNLESS(!series.empty(), folder << ": no DICOM image slices among its "
                                              << files.size() << " files (" << skipped
                                              << " are not DICOM images)");
  if (series.size() > 1) {
    std::ostringstream list;
    for (const auto& [uid, slices] : series) {
      list << "\n  " << (uid.empty() ? "(no series UID)" : uid) << ": " << slices.size()
           << " slices" << (slices.front().description.empty() ? "" : ", '" + slices.front().description + "'")
           << (slices.front().modality.empty() ? "" : ", " + slices.front().modality)
           << ", e.g. " << slices.front().file;
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
                        s.where() << ": " << s.rows << " x " << s.columns << " pixels, but "
                                  << first.where() << " has " << first.rows << " x " << first.columns);
    TROCAR_THROW_UNLESS((s.row_direction - first.row_direction).norm() < 1e-4 &&
                            (s.column_direction - first.column_direction).norm() < 1e-4,
                        s.where() << ": image orientation (0020,0037) differs from " << first.where()
                                  << "'s; the series is not one volume");
    TROCAR_THROW_UNLESS(
        (s.spacing_mm - first.spacing_mm).norm() < 1e-4 * first.spacing_mm.norm(),
        s.where() << ": pixel spacing (0028,0030) differs from " << first.where() << "'s");
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
                        slices[k].where() << ": same position as " << slices[k - 1].where()
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
                        slices[k].where() << ": " << d.norm() << " mm from the previous slice ("
                                          << slices[k - 1].where() << ") where the series steps "
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
  CheckVolumeGeometry(v, (is_folder ? path : folder) + " (DICOM series: pixel spacing (0028,0030), "
                                                       "slice positions (0020,0032))");
  CheckedVoxelCount(v.size, v.source);
  const long per_slice = static_cast<long>(first.rows) * first.columns;
  v.values.resize(static_cast<std::size_t>(per_slice) * n);
  for (int k = 0; k < n; ++k) {
    const Slice& s = slices[k];
    std::copy_n(s.values->begin() + per_slice * s.frame, per_slice, v.values.begin() + per_slice * k);
    if (v.files.empty() || v.files.back() != s.file) v.files.push_back(s.file);
  }
  std::sort(v.files.begin(), v.files.end());
  v.files.erase(std::unique(v.files.begin(), v.files.end()), v.files.end());
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
