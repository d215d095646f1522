#pragma once
/// @file
/// Network devices over OpenIGTLink (protocol 2, header version 1: a 58-byte big-endian header
/// with the body's CRC-64): a server that takes TRANSFORM and POSITION messages (poses) and SENSOR
/// messages (buttons: clutch, operator present) from several devices at once and sends messages
/// back (force feedback, instrument poses for 3D Slicer), and a DeviceInput that drives the
/// teleop core from one device. The messages each way are documented in docs/network-devices.md.
///
/// Everything from the network is untrusted: a body's size is bounded before anything is
/// allocated for it, the CRC is checked, each type's body must have its exact size, and
/// non-finite values are dropped; every drop is counted by reason, per device. The server listens
/// on localhost unless told otherwise. Messages are decoded with libopenigtlink; the sockets are
/// ours (poll), so that no read ever waits on a peer.

#include <atomic>
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
  long buttons = 0;       ///< button messages taken (SENSOR: clutch, present, others)
  long sent = 0;          ///< messages sent to the device (force feedback)
  long send_drops = 0;    ///< messages not sent: the device did not read fast enough
  long crc = 0;           ///< wrong CRC
  long malformed = 0;     ///< a body of the wrong size for its type
  long oversized = 0;     ///< a body larger than the bound (its connection is closed)
  long unknown_type = 0;  ///< a type this server does not take (skipped)
  long non_finite = 0;    ///< NaN or Inf values
  long truncated = 0;     ///< a message cut off by its connection closing
  /// Messages under this device's name from a second connection while the device's own is open
  /// and speaking (within a second): a name belongs to one connection at a time, so another
  /// client cannot take an arm over; it may once the owner closes or falls silent.
  long name_in_use = 0;
  long connections = 0;   ///< connections it was seen on (more than 1: reconnects)
  long drops() const { return crc + malformed + oversized + unknown_type + non_finite + truncated + name_in_use; }
};

/// Splits one connection's byte stream into OpenIGTLink messages and takes their poses: the
/// server's parser, on its own for tests and the fuzzer. It keeps at most one message's header
/// and bounded body between calls.
class IgtlStreamParser {
 public:
  /// A pose (TRANSFORM, POSITION) or the device's buttons (SENSOR: value 0 the clutch, 1 the
  /// operator's presence, the rest other buttons; non-zero is pressed).
  struct Pose {
    std::string device;
    Eigen::Isometry3d X_DH = Eigen::Isometry3d::Identity();  ///< translation in metres
    bool is_buttons = false;
    bool clutch = false;
    bool present = true;
    std::uint32_t pressed = 0;  ///< bit i: value i+2 pressed
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
  /// Open connections at most. When every slot is taken, a new connection takes the slot of
  /// the oldest one that has not yet sent a valid message (a device that has is never put out).
  int max_connections = 16;
  /// Connections from one peer address that have not yet sent a valid message, at most: a new
  /// one past it takes the slot of that address's oldest such connection, so one host's idle or
  /// garbage clients recycle their own slots and never those of other hosts (at most this many of
  /// `max_connections`). Devices that have spoken do not count. At least 1; above
  /// `max_connections` it is that.
  int max_unproved_per_address = 8;
  /// Seconds a connection may stay open without sending a valid message before it is closed
  /// (idle or garbage-only clients do not keep the slots from the devices).
  double idle_timeout_s = 5.0;
  /// Bytes waiting to be sent to one connection; a message that does not fit is dropped whole
  /// (a client that does not read never blocks the server or grows its memory).
  std::size_t max_pending = 1 << 18;
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
  /// The newest button state of `device` ("": the first device); false when it sent none.
  bool Buttons(const std::string& device, bool* clutch, bool* present, std::uint32_t* pressed = nullptr) const;

  /// Queues a whole message for the connection `device` last spoke on (never blocks; the server
  /// thread sends it). False when that device is not connected.
  bool Send(const std::string& device, std::string message);
  /// Queues a whole message for every connection (3D Slicer, devices).
  void Broadcast(std::string message);
  /// Messages broadcast, and those dropped for a connection that did not read.
  long broadcast_sent() const;
  long broadcast_drops() const;
  int connections() const;  ///< open connections
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
  /// Safe from any thread: whether the device is silent now, and the newest pose's latency (s).
  bool silent() const { return silent_now_.load(std::memory_order_relaxed); }
  double last_latency() const { return last_latency_.load(std::memory_order_relaxed); }

 private:
  const IgtlDeviceServer* server_;
  std::string device_;
  double silence_;
  std::uint64_t last_sequence_ = 0;
  bool silent_ = true;
  std::vector<double> latencies_;
  long silences_ = 0;
  std::atomic<bool> silent_now_{true};
  std::atomic<double> last_latency_{0.0};
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
  /// The device's buttons as a SENSOR message: [clutch, present, other buttons...].
  bool SendButtons(const std::string& device, bool clutch, bool present = true,
                   const std::vector<bool>& others = {});
  /// Raw bytes, as they are (tests inject faults with it). False when the connection closed.
  bool SendBytes(const std::string& bytes);
  /// Reads what the server sent, without waiting: messages by type ("SENSOR bad (size or
  /// CRC)", "TRANSFORM bad (size or CRC)" for those that do not decode).
  const std::map<std::string, long>& Received();
  /// The newest SENSOR values sent to `device` and their unit (OpenIGTLink's 64-bit unit code);
  /// false when none came. Call Received() first.
  bool LastSensor(const std::string& device, std::vector<double>* values, std::uint64_t* unit = nullptr) const;
  /// The largest force magnitude (N) in the SENSOR messages received so far.
  double max_force() const { return max_force_; }
  /// The newest TRANSFORM received for `name` (translation in metres); false when none came.
  bool LastTransform(const std::string& name, Eigen::Isometry3d* X) const;

 private:
  int fd_ = -1;
  std::vector<unsigned char> buffer_;
  std::map<std::string, long> received_;
  std::map<std::string, std::pair<std::vector<double>, std::uint64_t>> sensors_;
  std::map<std::string, Eigen::Isometry3d> transforms_;
  double max_force_ = 0.0;
};

/// OpenIGTLink messages, packed by libopenigtlink (header version 1, CRC-64, now as timestamp):
/// a TRANSFORM of `X` (translation given in metres, sent in `units` metres each), and a SENSOR of
/// float64 `values` with `unit` (igtl_unit.h's 64-bit code; 0: none).
std::string IgtlTransformMessage(const std::string& device, const Eigen::Isometry3d& X, double units = 0.001);
std::string IgtlSensorMessage(const std::string& device, const std::vector<double>& values, std::uint64_t unit = 0);
/// OpenIGTLink's unit code for newtons (SI derived unit 0x0B, exponent 1, no prefix).
std::uint64_t IgtlNewtonUnit();

}  // namespace trocar::control
