#pragma once
/// @file
/// Errors for bad user input (trocar::Error, TROCAR_THROW_UNLESS) versus the program's own
/// invariants (trocar::InternalError, TROCAR_CHECK): `trocar` prints the first as "error: ..."
/// and exits 1, the second as "internal error: FILE:LINE: ..." and exits 2, never aborting.
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

/// A bad value of a library's option (a field of its options struct, issue #45 item 3): the
/// library names the field as it spells it ("time_limit"), not a command-line flag or a YAML key;
/// `what()` is "time_limit: 0 s, expected a positive number of seconds". A front end says it in
/// its own words from option() and problem(): the CLI names its flag (apps/trocar, WithFlags); a
/// bench spec checks its keys itself, with their place in the YAML, before any options are built
/// (planners/bench/spec.cpp).
class OptionError : public Error {
 public:
  OptionError(std::string option, std::string problem);
  const std::string& option() const { return option_; }
  const std::string& problem() const { return problem_; }

 private:
  std::string option_, problem_;
};

/// Thrown when the program's own invariant fails: a bug, not the user's input (e.g. a plan file
/// trocar has just written does not parse back). Not a trocar::Error, so no handler of bad input
/// takes it for one.
class InternalError : public std::logic_error {
 public:
  using std::logic_error::logic_error;
};

namespace internal {
[[noreturn]] void ThrowError(const std::string& message);
/// Throws InternalError with the place ("planners/motion/verify.cpp:220: ...").
[[noreturn]] void ThrowInternal(const char* file, int line, const std::string& message);
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

/// Throws trocar::OptionError for option `option` (the field's name, a string) when `condition` is
/// false. Usage: TROCAR_OPTION_UNLESS(o.starts >= 1, "starts", o.starts << ", expected >= 1");
#define TROCAR_OPTION_UNLESS(condition, option, message)                              \
  do {                                                                                \
    if (!(condition)) {                                                               \
      std::ostringstream trocar_message_stream_;                                      \
      trocar_message_stream_ << message;                                              \
      throw ::trocar::OptionError(option, trocar_message_stream_.str());             \
    }                                                                                 \
  } while (false)

/// Throws trocar::InternalError naming this source line when the program's own invariant
/// `condition` is false. Usage: TROCAR_CHECK(plans.size() == verifications.size(), "...");
#define TROCAR_CHECK(condition, message)                                                  \
  do {                                                                                    \
    if (!(condition)) {                                                                   \
      std::ostringstream trocar_message_stream_;                                          \
      trocar_message_stream_ << message;                                                  \
      ::trocar::internal::ThrowInternal(__FILE__, __LINE__, trocar_message_stream_.str()); \
    }                                                                                     \
  } while (false)

/// Throws trocar::Error unconditionally with a streamed message.
#define TROCAR_THROW(message) TROCAR_THROW_UNLESS(false, message)
