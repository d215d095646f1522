#include "common/limits.hpp"

#include <cerrno>
#include <cstdlib>
#include <limits>
#include <mutex>
#include <sstream>

#include "common/error.hpp"

namespace trocar {
namespace {

std::mutex& LimitsMutex() {
  static std::mutex mutex;
  return mutex;
}

InputLimits* current = nullptr;

template <typename T>
void FromEnvironment(const char* name, T* value) {
  const char* text = std::getenv(name);
  if (text == nullptr || *text == '\0') return;
  char* end = nullptr;
  errno = 0;
  const unsigned long long parsed = std::strtoull(text, &end, 10);
  TROCAR_THROW_UNLESS(errno == 0 && end != text && *end == '\0' && parsed > 0 && text[0] != '-' &&
                          parsed <= static_cast<unsigned long long>(std::numeric_limits<T>::max()),
                      "environment variable " << name << "='" << text
                                              << "': expected a positive integer");
  *value = static_cast<T>(parsed);
}

}  // namespace

const InputLimits& Limits() {
  std::lock_guard<std::mutex> lock(LimitsMutex());
  if (current == nullptr) {
    InputLimits limits;
    FromEnvironment("TROCAR_MAX_FILE_BYTES", &limits.max_file_bytes);
    FromEnvironment("TROCAR_MAX_TEXT_BYTES", &limits.max_text_bytes);
    FromEnvironment("TROCAR_MAX_VOXELS", &limits.max_voxels);
    FromEnvironment("TROCAR_MAX_XML_DEPTH", &limits.max_xml_depth);
    FromEnvironment("TROCAR_MAX_INCLUDES", &limits.max_includes);
    FromEnvironment("TROCAR_MAX_YAML_NODES", &limits.max_yaml_nodes);
    FromEnvironment("TROCAR_MAX_JSON_VALUES", &limits.max_json_values);
    FromEnvironment("TROCAR_MAX_JSON_DEPTH", &limits.max_json_depth);
    FromEnvironment("TROCAR_MAX_JSON_STRING", &limits.max_json_string);
    FromEnvironment("TROCAR_MAX_RECORDED_SAMPLES", &limits.max_recorded_samples);
    current = new InputLimits(limits);  // lives for the process
  }
  return *current;
}

void SetLimits(const InputLimits& limits) {
  std::lock_guard<std::mutex> lock(LimitsMutex());
  if (current == nullptr) {
    current = new InputLimits(limits);
  } else {
    *current = limits;
  }
}

std::string LimitHint(std::uint64_t limit, const char* env) {
  std::ostringstream out;
  out << "(limit " << limit << ", set " << env << " to raise it)";
  return out.str();
}

std::uint64_t CheckedVoxelCount(const Eigen::Vector3i& size, const std::string& what) {
  TROCAR_THROW_UNLESS((size.array() > 0).all(),
                      what << ": sizes " << size.transpose() << " must be positive");
  const std::uint64_t limit = Limits().max_voxels;
  unsigned __int128 count = 1;
  for (int a = 0; a < 3; ++a) count *= static_cast<unsigned __int128>(size[a]);
  TROCAR_THROW_UNLESS(count <= limit, what << ": sizes " << size.transpose() << " make "
                                           << static_cast<long double>(count)
                                           << " voxels, more than trocar reads "
                                           << LimitHint(limit, "TROCAR_MAX_VOXELS"));
  return static_cast<std::uint64_t>(count);
}

}  // namespace trocar
