// Fuzz target for plan files (trocar check --plan): the JSON and every field read before the case
// and robot it names are loaded. The inputs name files that do not exist here, so a plan that gets
// that far ends in an error naming them (a full check per input would cost a patient import).
#include <sstream>

#include "apps/trocar/commands.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string path = trocar::fuzz::WriteInput("plan/plan.json", data, size);
  trocar::fuzz::Expect([&] {
    std::ostringstream out;
    trocar::apps::CheckPlanFile(path, out);
  });
  return 0;
}
