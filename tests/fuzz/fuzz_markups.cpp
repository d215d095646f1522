// Fuzz target for 3D Slicer markups (.mrk.json): targets and port candidates.
#include "fuzz_util.hpp"
#include "patient/markups.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = trocar::fuzz::WriteInput("m.mrk.json", data, size);
  trocar::fuzz::Expect([&] { trocar::patient::LoadMarkups(path); });
  return 0;
}
