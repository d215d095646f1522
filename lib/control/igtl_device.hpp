#pragma once
/// @file
/// Network devices over OpenIGTLink (protocol 2, header version 1: a 58-byte big-endian header
/// with the body's CRC-64): a server that takes TRANSFORM and POSITION messages from several
/// devices at once, and a DeviceInput that drives the teleop core from one of them.
///
/// Everything from the network is untrusted: a body's size is bounded before anything is
/// allocated for it, the CRC is checked, each type's body must have its exact size, and
/// non-finite values are dropped; every drop is counted by reason, per device. The server listens
/// on localhost unless told otherwise. Messages are decoded with libopenigtlink; the sockets are
/// ours (poll), so that no read ever waits on a peer.

#include <chrono>
#include <functional>
#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "control/device_input.hpp"

namespace trocar::control {

/// What arrived from one device, and what was dropped, by reason.
struct DeviceCounters {
  long messages = 0;      ///< poses taken
  long crc = 0;           ///< wrong CRC
  long malformed = 0;     ///< a body of the wrong size for its type
  long oversized = 0;     ///< a body larger than the bound (its connection is closed)
  long unknown_type = 0;  ///< a type this server does not take (skipped)
  long non_finite = 0;    ///< NaN or Inf values
  long truncated = 0;     ///< a message cut off by its connection closing
  long connections = 0;   ///< connections it was seen on (more than 1: reconnects)
  long drops() const { return crc + malformed + oversized + unknown_type + non_finite + truncated; }
};

/// Splits one connection's byte stream into OpenIGTLink messages and takes their poses: the
/// server's parser, on its own for tests and the fuzzer. It keeps at most one message's header
/// and bounded body between calls.
class IgtlStreamParser {
 public:
  struct Pose {
    std::string device;
    Eigen::Isometry3d X_DH = Eigen::Isometry3d::Identity();  ///< translation in metres
  };
  /// `units(device)`: metres per unit of that device's translations.
  IgtlStreamParser(std::size_t max_body, std::function<double(const std::string&)> units);
  /// Takes `n` more bytes. Poses are appended to `poses`, drops counted in `counters` by device.
  /// @return false when the stream cannot go on (a body over the bound): close it.
  bool Feed(const unsigned char* data, std::size_t n, std::vector<Pose>* poses,
            std::map<std::string, DeviceCounters>* counters);
  /// At the stream's end: a message left incomplete is counted as truncated.
  void Close(std::map<std::string, DeviceCounters>* counters);
  std::size_t buffered() const { return buffer_.size(); }

 private:
  std::size_t max_body_;
  std::function<double(const std::string&)> units_;
  std::vector<unsigned char> buffer_;
  std::string last_name_;
};

struct IgtlServerOptions {
  std::string address = "127.0.0.1";  ///< an explicit option binds elsewhere ("0.0.0.0": all)
  int port = 18944;                   ///< OpenIGTLink's usual port; 0: any free port
  std::size_t max_body = 1 << 16;     ///< bytes; a larger body closes its connection
  int max_connections = 16;
  /// Metres per unit of a device's translations, by device name; others: `default_units`
  /// (OpenIGTLink's millimetres; the dVRK's bridge sends metres: 1).
  std::map<std::string, double> units;
  double default_units = 0.001;
};

/// Parses "[ADDRESS:]PORT". @throws trocar::Error naming the text.
void ParseListenAddress(const std::string& text, IgtlServerOptions* options);

class IgtlDeviceServer {
 public:
  /// Binds and starts listening in its own thread.
  /// @throws trocar::Error naming the address and port when it cannot bind (in use, not local).
  explicit IgtlDeviceServer(const IgtlServerOptions& options);
  ~IgtlDeviceServer();
  IgtlDeviceServer(const IgtlDeviceServer&) = delete;
  IgtlDeviceServer& operator=(const IgtlDeviceServer&) = delete;

  int port() const;  ///< the bound port
  const std::string& address() const;

  /// The newest pose of `device` ("": the first device that sent a valid pose), its sequence
  /// number (1, 2, ...) and arrival time. False when that device has sent none.
  bool Latest(const std::string& device, DeviceSample* sample, std::uint64_t* sequence,
              std::chrono::steady_clock::time_point* arrival, std::string* name = nullptr) const;
  /// Counters per device name (drops before a device name was read count under "").
  std::map<std::string, DeviceCounters> Counters() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Drives the teleop core from one device of a server: the newest pose at each control step.
/// A device silent for longer than `silence` (s) is absent (the arm holds; when it speaks again
/// the mapping re-anchors, without a jump).
class NetworkDeviceInput final : public DeviceInput {
 public:
  NetworkDeviceInput(const IgtlDeviceServer* server, std::string device, double silence = 0.1);
  std::string name() const override;
  DeviceSample Sample(double t) override;

  /// Time from a pose's arrival to the control step that took it (s), per new pose.
  const std::vector<double>& latencies() const { return latencies_; }
  long silences() const { return silences_; }  ///< times the device went silent

 private:
  const IgtlDeviceServer* server_;
  std::string device_;
  double silence_;
  std::uint64_t last_sequence_ = 0;
  bool silent_ = true;
  std::vector<double> latencies_;
  long silences_ = 0;
};

/// A device's side: connects to a server and sends poses as OpenIGTLink TRANSFORM messages
/// (translations in `units` metres each: 0.001 for millimetres), and counts what comes back.
class IgtlDeviceClient {
 public:
  /// @throws trocar::Error naming the address when it cannot connect within `timeout` (s).
  IgtlDeviceClient(const std::string& address, int port, double timeout = 5.0);
  ~IgtlDeviceClient();
  IgtlDeviceClient(const IgtlDeviceClient&) = delete;
  IgtlDeviceClient& operator=(const IgtlDeviceClient&) = delete;

  /// False when the server has gone (the connection closed).
  bool SendPose(const std::string& device, const Eigen::Isometry3d& X_DH, double units = 0.001);
  /// Raw bytes, as they are (tests inject faults with it). False when the connection closed.
  bool SendBytes(const std::string& bytes);
  /// Reads what the server sent, without waiting: messages by type.
  const std::map<std::string, long>& Received();

 private:
  int fd_ = -1;
  std::vector<unsigned char> buffer_;
  std::map<std::string, long> received_;
};

}  // namespace trocar::control
