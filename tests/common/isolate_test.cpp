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
#include <future>
#include <memory>
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

namespace trocar {
namespace {

TEST(IsolatedWorker, OneChildServesManyRequestsAndADeadOneIsReplaced) {
  IsolatedWorker worker([](const std::string& request, std::string* answer) {
    if (request == "abort") std::abort();
    if (request == "refuse") throw Error("refused: " + request);
    *answer = "echo " + request + " from " + std::to_string(::getpid());
  });
  std::string first_pid;
  for (int k = 0; k < 50; ++k) {
    const std::string answer = worker.Call("item", std::to_string(k));
    ASSERT_EQ(answer.rfind("echo " + std::to_string(k) + " from ", 0), 0u) << answer;
    const std::string pid = answer.substr(answer.rfind(' ') + 1);
    if (k == 0) first_pid = pid;
    EXPECT_EQ(pid, first_pid);  // the same process throughout
    EXPECT_NE(pid, std::to_string(::getpid()));  // and not this one
  }
  EXPECT_EQ(worker.started(), 1);
  try {
    worker.Call("item", "refuse");
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_STREQ(e.what(), "refused: refuse");
  }
  EXPECT_EQ(worker.started(), 1);  // a refusal is an answer: the child lives on
  try {
    worker.Call("slice_0042.dcm", "abort");
    ADD_FAILURE() << "no error";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("slice_0042.dcm: the decoder crashed"), std::string::npos) << e.what();
  }
  const std::string after = worker.Call("item", "x");  // a new child
  EXPECT_EQ(worker.started(), 2);
  EXPECT_NE(after.substr(after.rfind(' ') + 1), first_pid);
}

// A worker's child forked while another worker lives holds a copy of that worker's socket end:
// closing it is then no end of file for the first child. Ending the first worker must not wait
// for one (it hung before the worker killed its child).
TEST(IsolatedWorker, EndingOneWorkerWhileAnotherLivesDoesNotHang) {
  auto echo = [](const std::string& request, std::string* answer) { *answer = request; };
  auto first = std::make_unique<IsolatedWorker>(echo);
  EXPECT_EQ(first->Call("a", "1"), "1");
  IsolatedWorker second(echo);
  EXPECT_EQ(second.Call("b", "2"), "2");  // forked with a copy of the first's end
  auto done = std::async(std::launch::async, [&first] { first.reset(); });
  ASSERT_EQ(done.wait_for(std::chrono::seconds(20)), std::future_status::ready)
      << "ending the first worker hangs";
  EXPECT_EQ(second.Call("b", "3"), "3");
}

TEST(IsolatedWorker, LargeRequestsAndAnswersBothWays) {
  IsolatedWorker worker([](const std::string& request, std::string* answer) {
    answer->assign(request.rbegin(), request.rend());
  });
  std::string request;
  for (unsigned k = 0; k < 5000000u; ++k) request.push_back(static_cast<char>(k * 31u % 251u));
  const std::string answer = worker.Call("big", request);
  EXPECT_EQ(answer, std::string(request.rbegin(), request.rend()));
}

}  // namespace
}  // namespace trocar
