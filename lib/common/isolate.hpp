#pragma once
/// @file
/// Runs third-party decoding in a child process, so that a library that aborts, asserts,
/// crashes or hangs on a damaged file (Debian's GDCM asserts on many malformed DICOM files) ends
/// in a trocar::Error naming the file instead of taking trocar down with it.
///
/// The child is a fork of this process. An IsolatedWorker forks once and then serves requests
/// (bytes in, bytes out, over a Unix socket; its standard error through a pipe) one after
/// another, so a series of hundreds of files costs one fork, made while the caller is still
/// small (fork copies the page tables of all the memory the caller holds: 16 ms at 300 MB). A
/// child that dies is replaced at the next request; the worker's end kills its child.
/// The parent bounds the answer it accepts (`max_output_bytes`) and how long it waits
/// (`timeout_s`, per request). What the child prints to its standard error is kept (the last
/// 2 KiB) for the message.

#include <sys/types.h>

#include <cstdint>
#include <functional>
#include <string>

namespace trocar {

struct IsolateOptions {
  /// An answer beyond this is refused (the child is stopped): the caller's own size limit.
  std::uint64_t max_output_bytes = 64ull << 20;
  /// A request still unanswered after this many seconds is an error (the child is stopped).
  double timeout_s = 60.0;
};

/// A child process that answers requests with `work(request, &answer)`.
/// A trocar::Error thrown by `work` is re-thrown in the caller with the same message; a crash
/// (signal), an abort, another exception, a time-out or an answer over the limit is a
/// trocar::Error that starts with the request's `what` and says which, with the last lines the
/// child printed (an assertion's text, say). Not thread safe: one caller at a time.
class IsolatedWorker {
 public:
  using Work = std::function<void(const std::string& request, std::string* answer)>;
  explicit IsolatedWorker(Work work, IsolateOptions options = {});
  ~IsolatedWorker();
  IsolatedWorker(const IsolatedWorker&) = delete;
  IsolatedWorker& operator=(const IsolatedWorker&) = delete;

  /// Sends `request` to the child (started now if there is none) and returns its answer.
  /// @param what names the input in messages (a file).
  /// @param timeout_s this request's time limit; the options' when negative.
  /// @throws trocar::Error as above, or when the child cannot be started.
  std::string Call(const std::string& what, const std::string& request, double timeout_s = -1.0);

  /// Children started so far (1 while none has died).
  int started() const { return started_; }

 private:
  void Start(const std::string& what);
  void Stop();
  int Reap();  // closes our ends, waits for the child, returns its status
  [[noreturn]] void Serve();

  Work work_;
  IsolateOptions options_;
  pid_t pid_ = -1;
  int to_child_ = -1, from_child_ = -1, child_err_ = -1;
  int started_ = 0;
  std::string err_;  // the child's standard error, last bytes
};

/// One request to a fresh child: runs `work` there and returns what it left in its output
/// string (empty at first). The child sees the caller's memory as it was.
/// @throws trocar::Error as IsolatedWorker::Call does.
std::string RunIsolated(const std::string& what, const std::function<void(std::string* out)>& work,
                        const IsolateOptions& options = {});

}  // namespace trocar
