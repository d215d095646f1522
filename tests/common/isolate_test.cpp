// The child-process guard around third-party decoders (lib/common/isolate): whatever the child
// does (answers, refuses, aborts, crashes, hangs, floods), the caller gets an answer or a
// trocar::Error naming the input, and goes on.
#include <gtest/gtest.h>

#include <signal.h>
#include <unistd.h>

#include <cassert>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "common/error.hpp"
#include "common/isolate.hpp"

namespace trocar {
namespace {

std::string ErrorOf(const std::function<void(std::string*)>& work, const IsolateOptions& options = {}) {
  try {
    RunIsolated("scan/slice.dcm", work, options);
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

TEST(Isolate, AnswerComesBackWholeIncludingZeroBytesAndLargeOutputs) {
  std::string expected;
  for (unsigned k = 0; k < 3000000u; ++k) expected.push_back(static_cast<char>(k * 7919u % 256u));
  const std::string got = RunIsolated("big", [&](std::string* out) { *out += expected; });
  EXPECT_EQ(got, expected);  // several pipe buffers, zero bytes inside
  EXPECT_EQ(RunIsolated("empty", [](std::string*) {}), "");
}

TEST(Isolate, TheChildSeesTheCallersMemoryAndCannotChangeIt) {
  int value = 41;
  const std::string got = RunIsolated("copy", [&](std::string* out) {
    ++value;
    *out = std::to_string(value);
  });
  EXPECT_EQ(got, "42");
  EXPECT_EQ(value, 41);
}

TEST(Isolate, ARefusalKeepsItsMessage) {
  EXPECT_EQ(ErrorOf([](std::string*) { throw Error("scan/slice.dcm: rows (0028,0010) missing"); }),
            "scan/slice.dcm: rows (0028,0010) missing");
}

TEST(Isolate, AnAbortIsAnErrorNamingTheInputWithWhatTheChildPrinted) {
  const std::string e = ErrorOf([](std::string*) {
    std::fprintf(stderr, "gdcmSomething.cxx:42: Assertion `length != 0' failed.\n");
    std::abort();
  });
  EXPECT_EQ(e.rfind("scan/slice.dcm: ", 0), 0u) << e;
  EXPECT_NE(e.find("crashed"), std::string::npos) << e;
  EXPECT_NE(e.find("signal 6"), std::string::npos) << e;
  EXPECT_NE(e.find("Assertion `length != 0' failed."), std::string::npos) << e;
}

TEST(Isolate, ASegmentationFaultIsAnError) {
  // raise, not a store through a null pointer: under UBSan that is a report and an exit, not
  // a signal, and this test is about the signal.
  const std::string e = ErrorOf([](std::string*) { ::raise(SIGSEGV); });
  EXPECT_NE(e.find("crashed"), std::string::npos) << e;
}

TEST(Isolate, AnotherExceptionIsAnErrorNotARethrow) {
  const std::string e = ErrorOf([](std::string*) { throw std::length_error("vector::reserve"); });
  EXPECT_EQ(e.rfind("scan/slice.dcm: ", 0), 0u) << e;
  EXPECT_NE(e.find("vector::reserve"), std::string::npos) << e;
}

TEST(Isolate, AHangIsStoppedAtTheTimeOut) {
  IsolateOptions options;
  options.timeout_s = 0.5;
  const auto start = std::chrono::steady_clock::now();
  const std::string e = ErrorOf([](std::string*) { ::sleep(30); }, options);
  const double took = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  EXPECT_NE(e.find("did not finish within 0.5 s"), std::string::npos) << e;
  EXPECT_LT(took, 10.0);  // killed, not waited for
}

TEST(Isolate, OutputOverTheLimitIsRefused) {
  IsolateOptions options;
  options.max_output_bytes = 1000;
  EXPECT_EQ(RunIsolated("fits", [](std::string* out) { out->assign(1000, 'x'); }, options).size(), 1000u);
  const std::string e = ErrorOf([](std::string* out) { out->assign(1'000'000, 'x'); }, options);
  EXPECT_NE(e.find("more than 1000 bytes"), std::string::npos) << e;
}

TEST(Isolate, AnExitWithoutAnswerIsAnError) {
  const std::string e = ErrorOf([](std::string*) { ::_exit(3); });
  EXPECT_NE(e.find("without an answer (exit status 3)"), std::string::npos) << e;
}

}  // namespace
}  // namespace trocar
