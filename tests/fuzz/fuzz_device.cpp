// Fuzz target for device files (trocar teleop --devices): YAML, names, units, scales and the
// device-to-camera rotation, each within its physical range.
#include "control/device_config.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = trocar::fuzz::WriteInput("devices.yaml", data, size);
  trocar::fuzz::Expect([&] { trocar::control::ReadDeviceConfig(path); });
  return 0;
}
