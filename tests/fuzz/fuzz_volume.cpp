// Fuzz target for the CT readers: NRRD, NIfTI-1 (raw or gzip) and MetaImage, picked by the
// target's name (TROCAR_FUZZ_FORMAT at compile time), so that each format has its own corpus.
#include "fuzz_util.hpp"
#include "patient/volume.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  std::string name = TROCAR_FUZZ_FORMAT;
  // NIfTI: a gzip stream (magic 1f 8b) is read as .nii.gz.
  if (name == "ct.nii" && size >= 2 && data[0] == 0x1f && data[1] == 0x8b) name = "ct.nii.gz";
  const std::string path = trocar::fuzz::WriteInput(name, data, size);
  trocar::fuzz::Expect([&] { trocar::patient::LoadVolume(path); });
  return 0;
}
