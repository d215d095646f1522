#include "common/error.hpp"

namespace trocar::internal {

void ThrowError(const std::string& message) { throw Error(message); }

}  // namespace trocar::internal
