// Fuzz target for bench specs (trocar bench SPEC.yaml): the YAML and every field, checked whole
// before anything runs. Patients and robots named by an input do not exist here, so a spec that
// gets that far ends in an error naming them.
#include "bench/spec.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = trocar::fuzz::WriteInput("spec/bench.yaml", data, size);
  trocar::fuzz::Expect([&] { trocar::planners::ReadBenchSpec(path, "robot.yaml"); });
  return 0;
}
