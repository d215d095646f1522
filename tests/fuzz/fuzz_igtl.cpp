// Fuzz target for the OpenIGTLink device server's parser (network input, untrusted): the bytes
// are fed in pieces whose sizes the input's first byte chooses, as they would arrive on a socket.
#include <vector>

#include "control/igtl_device.hpp"
#include "fuzz_util.hpp"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  trocar::fuzz::Expect([&] {
    trocar::control::IgtlStreamParser parser(1 << 16, [](const std::string& name) {
      return name == "metres" ? 1.0 : 0.001;
    });
    std::vector<trocar::control::IgtlStreamParser::Pose> poses;
    std::map<std::string, trocar::control::DeviceCounters> counters;
    const std::size_t piece = size > 0 ? 1 + data[0] % 97 : 1;
    for (std::size_t at = size > 0 ? 1 : 0; at < size; at += piece) {
      if (!parser.Feed(data + at, std::min(piece, size - at), &poses, &counters)) break;
      if (parser.buffered() > 58 + (1 << 16) + 97) __builtin_trap();  // the bound must hold
    }
    parser.Close(&counters);
    for (const auto& p : poses)
      if (!p.X_DH.matrix().allFinite()) __builtin_trap();
  });
  return 0;
}
