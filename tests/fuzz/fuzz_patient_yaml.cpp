// Fuzz target for patient.yaml (the case file): every field, with the files it may name present.
#include "fuzz_util.hpp"
#include "patient/case_file.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const bool files = [] {
    for (const char* name : {"case/ct.nrrd", "case/heart.nrrd", "case/markups/LAD.mrk.json",
                             "case/labels.nii.gz", "case/names.json"}) {
      trocar::fuzz::WriteInput(name, reinterpret_cast<const uint8_t*>("x"), 1);
    }
    return true;
  }();
  (void)files;
  trocar::fuzz::WriteInput("case/patient.yaml", data, size);
  trocar::fuzz::Expect([&] { trocar::patient::ReadCase(trocar::fuzz::WorkDir() + "/case"); });
  return 0;
}
