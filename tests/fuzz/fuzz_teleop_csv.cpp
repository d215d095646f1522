// Fuzz target for recorded hand motion (teleop --input FILE.csv).
#include "control/device_input.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = trocar::fuzz::WriteInput("motion.csv", data, size);
  trocar::fuzz::Expect([&] {
    trocar::control::CsvReplayInput input(path);
    for (double t : {0.0, 0.5, 1e9}) input.Sample(t);
  });
  return 0;
}
