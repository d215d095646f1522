#pragma once
/// @file
/// Runs a piece of third-party decoding in a child process, so that a library that aborts,
/// asserts, crashes or hangs on a damaged file (Debian's GDCM asserts on many malformed DICOM
/// files) ends in a trocar::Error naming the file instead of taking trocar down with it.
///
/// The child is a fork of this process: it sees the caller's memory as it was (the bytes already
/// read and checked), runs `work`, and leaves the bytes `work` produced in an in-memory file
/// (memfd) sealed at `max_output_bytes`; the parent reads them once the child has ended, within
/// `timeout_s`. What the child prints to its standard error is kept (64 KiB) for the message.

#include <cstdint>
#include <functional>
#include <string>

namespace trocar {

struct IsolateOptions {
  /// Output beyond this is refused (the child is killed): the caller's own size limit.
  std::uint64_t max_output_bytes = 64ull << 20;
  /// A child still running after this many seconds is killed and the run is an error.
  double timeout_s = 60.0;
};

/// Runs `work` in a forked child and returns what it left in its output string (empty at first).
/// A trocar::Error thrown by `work` is re-thrown in the caller with the same message; a crash
/// (signal), an abort, another exception, a time-out or output over the limit is a
/// trocar::Error that starts with `what` and says which, with the last lines the child printed
/// to its standard error (an assertion's text, say).
/// @throws trocar::Error as above, or when the child cannot be started.
std::string RunIsolated(const std::string& what, const std::function<void(std::string* out)>& work,
                        const IsolateOptions& options = {});

}  // namespace trocar
