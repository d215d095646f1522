// Fuzz target for the DICOM reader: one file, structure-checked by trocar, then decoded by GDCM.
#include "fuzz_util.hpp"
#include "patient/volume.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = trocar::fuzz::WriteInput("series/slice.dcm", data, size);
  trocar::fuzz::Expect([&] { trocar::patient::LoadDicomSeries(path); });
  return 0;
}
