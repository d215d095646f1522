#include "common/error.hpp"

#include <utility>

namespace trocar {

OptionError::OptionError(std::string option, std::string problem)
    : Error(option + ": " + problem), option_(std::move(option)), problem_(std::move(problem)) {}

}  // namespace trocar

namespace trocar::internal {

void ThrowError(const std::string& message) { throw Error(message); }

void ThrowInternal(const char* file, int line, const std::string& message) {
  // The path from the source tree's top folder (lib/, planners/, viz/, apps/, tests/, bench/).
  std::string place = file ? file : "?";
  for (const char* top : {"/lib/", "/planners/", "/viz/", "/apps/", "/tests/", "/bench/"}) {
    const std::size_t at = place.rfind(top);
    if (at != std::string::npos) {
      place = place.substr(at + 1);
      break;
    }
  }
  throw InternalError(place + ":" + std::to_string(line) + ": " + message);
}

}  // namespace trocar::internal
