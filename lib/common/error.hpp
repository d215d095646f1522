#pragma once
/// @file
/// Errors for bad user input (thrown) versus internal invariants (assert).
///
/// Every message names the place (file, field, element), the offending value and what was
/// expected, e.g. `robots/arm.yaml:12:5: joints[2].limits: lower 1.2 > upper 0.9`.

#include <sstream>
#include <stdexcept>
#include <string>

namespace trocar {

/// Thrown for bad user input: malformed files, out-of-range values, NaN, missing files.
class Error : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

namespace internal {
[[noreturn]] void ThrowError(const std::string& message);
}  // namespace internal

}  // namespace trocar

/// Throws trocar::Error with a message built by streaming `message` when `condition` is false.
/// Usage: TROCAR_THROW_UNLESS(lower <= upper, path << ": lower " << lower << " > upper " << upper);
#define TROCAR_THROW_UNLESS(condition, message)      \
  do {                                               \
    if (!(condition)) {                              \
      std::ostringstream trocar_message_stream_;     \
      trocar_message_stream_ << message;             \
      ::trocar::internal::ThrowError(trocar_message_stream_.str()); \
    }                                                \
  } while (false)

/// Throws trocar::Error unconditionally with a streamed message.
#define TROCAR_THROW(message) TROCAR_THROW_UNLESS(false, message)
