// Fuzz target for the model cache (cache/model.bin). The mutated bytes are sealed with a valid
// checksum half of the time, so that the parser behind the checksum is explored as well.
#include <cstring>

#include "fuzz_util.hpp"
#include "patient/model_cache.hpp"
#include "patient/patient_model.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::string bytes(reinterpret_cast<const char*>(data), size);
  std::uint64_t key = 0;
  if (bytes.size() >= 16) std::memcpy(&key, bytes.data() + 8, 8);
  if (bytes.size() >= 32 && (bytes[bytes.size() / 2] & 1)) {
    const std::uint64_t sum = trocar::patient::ModelChecksum(bytes.data(), bytes.size() - 16);
    std::memcpy(&bytes[bytes.size() - 16], &sum, 8);
  }
  trocar::fuzz::Expect([&] {
    trocar::patient::PatientModel model;
    trocar::patient::ImportReport report;
    std::string damage;
    trocar::patient::DeserializeModel(bytes, key, &model, &report, &damage);
  });
  return 0;
}
