#include "control/igtl_device.hpp"

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstring>
#include <mutex>
#include <thread>

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <netinet/tcp.h>
#include <poll.h>
#include <sys/socket.h>
#include <unistd.h>

#include <igtlMessageHeader.h>
#include <igtlPositionMessage.h>
#include <igtlSensorMessage.h>
#include <igtlTransformMessage.h>
#include <igtlUnit.h>

#include "common/error.hpp"

namespace trocar::control {
namespace {

constexpr std::size_t kHeaderSize = 58;

std::uint64_t BigEndian64(const unsigned char* p) {
  std::uint64_t v = 0;
  for (int i = 0; i < 8; ++i) v = (v << 8) | p[i];
  return v;
}

std::string Field(const unsigned char* p, std::size_t n) {
  std::size_t len = 0;
  while (len < n && p[len] != 0) ++len;
  return std::string(reinterpret_cast<const char*>(p), len);
}

/// libopenigtlink's header of the message at `m` (58 bytes).
igtl::MessageHeader::Pointer UnpackHeader(const unsigned char* m) {
  igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
  header->InitPack();
  std::memcpy(header->GetPackPointer(), m, kHeaderSize);
  header->Unpack();
  return header;
}

/// The body of the message at `m` unpacked by libopenigtlink as a `Message`; null when its size
/// is not the one the header gives or its CRC does not check.
template <typename Message>
typename Message::Pointer UnpackBody(const igtl::MessageHeader::Pointer& header, const unsigned char* m,
                                     std::size_t body_size) {
  typename Message::Pointer message = Message::New();
  message->SetMessageHeader(header);
  message->AllocatePack();
  if (static_cast<std::size_t>(message->GetPackBodySize()) != body_size) return typename Message::Pointer();
  std::memcpy(message->GetPackBodyPointer(), m + kHeaderSize, body_size);
  if (!(message->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) return typename Message::Pointer();
  return message;
}

/// One complete message (header and body in `m`): a pose, or a drop counted.
bool TakeMessage(const unsigned char* m, std::size_t body_size, double units, IgtlStreamParser::Pose* pose,
                 DeviceCounters* count) {
  const std::string type = Field(m + 2, 12);
  const bool transform = type == "TRANSFORM", position = type == "POSITION", sensor = type == "SENSOR";
  if (!transform && !position && !sensor) {
    ++count->unknown_type;
    return false;
  }
  // SENSOR (buttons): 1 byte count, 1 byte status, 8 bytes unit, then count float64 values.
  const std::size_t sensor_values = sensor && body_size >= 10 ? m[kHeaderSize] : 0;
  if (m[0] != 0 || m[1] != 1 || (transform && body_size != 48) ||
      (position && body_size != 12 && body_size != 24 && body_size != 28) ||
      (sensor && (sensor_values < 1 || sensor_values > 32 || body_size != 10 + 8 * sensor_values))) {
    ++count->malformed;
    return false;
  }
  const igtl::MessageHeader::Pointer header = UnpackHeader(m);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  // The sizes are checked above: a body that does not unpack fails its CRC.
  if (sensor) {
    const igtl::SensorMessage::Pointer sm = UnpackBody<igtl::SensorMessage>(header, m, body_size);
    if (sm.IsNull()) {
      ++count->crc;
      return false;
    }
    pose->pressed = 0;
    for (unsigned i = 0; i < sm->GetLength(); ++i) {
      const double v = sm->GetValue(i);
      if (!std::isfinite(v)) {
        ++count->non_finite;
        return false;
      }
      if (i == 0) pose->clutch = v != 0.0;
      else if (i == 1) pose->present = v != 0.0;
      else if (v != 0.0) pose->pressed |= 1u << (i - 2);
    }
    pose->device = Field(m + 14, 20);
    pose->is_buttons = true;
    return true;
  }
  if (transform) {
    const igtl::TransformMessage::Pointer t = UnpackBody<igtl::TransformMessage>(header, m, body_size);
    if (t.IsNull()) {
      ++count->crc;
      return false;
    }
    igtl::Matrix4x4 matrix;
    t->GetMatrix(matrix);
    Eigen::Matrix3d R;
    for (int r = 0; r < 3; ++r)
      for (int k = 0; k < 3; ++k) R(r, k) = matrix[r][k];
    const Eigen::Vector3d p(matrix[0][3], matrix[1][3], matrix[2][3]);
    if (!R.allFinite() || !p.allFinite()) {
      ++count->non_finite;
      return false;
    }
    // A rotation within float precision: re-orthonormalised; anything else is malformed.
    if ((R.transpose() * R - Eigen::Matrix3d::Identity()).norm() > 1e-3 || R.determinant() < 0) {
      ++count->malformed;
      return false;
    }
    const Eigen::JacobiSVD<Eigen::Matrix3d> svd(R, Eigen::ComputeFullU | Eigen::ComputeFullV);
    X.linear() = svd.matrixU() * svd.matrixV().transpose();
    X.translation() = p * units;
  } else {
    const igtl::PositionMessage::Pointer pm = UnpackBody<igtl::PositionMessage>(header, m, body_size);
    if (pm.IsNull()) {
      ++count->crc;
      return false;
    }
    float pos[3] = {0, 0, 0}, q[4] = {0, 0, 0, 1};
    pm->GetPosition(pos);
    if (body_size > 12) pm->GetQuaternion(q);  // x, y, z, w
    const Eigen::Vector3d p(pos[0], pos[1], pos[2]);
    const Eigen::Quaterniond quat(q[3], q[0], q[1], q[2]);
    if (!p.allFinite() || !quat.coeffs().allFinite()) {
      ++count->non_finite;
      return false;
    }
    if (quat.norm() < 1e-6) {
      ++count->malformed;
      return false;
    }
    X.linear() = quat.normalized().toRotationMatrix();
    X.translation() = p * units;
  }
  if (!X.matrix().allFinite()) {  // finite floats times units can overflow
    ++count->non_finite;
    return false;
  }
  pose->device = Field(m + 14, 20);
  pose->X_DH = X;
  return true;
}

}  // namespace

IgtlStreamParser::IgtlStreamParser(std::size_t max_body, std::function<double(const std::string&)> units)
    : max_body_(max_body), units_(std::move(units)) {}

bool IgtlStreamParser::Feed(const unsigned char* data, std::size_t n, std::vector<Pose>* poses,
                            std::map<std::string, DeviceCounters>* counters) {
  buffer_.insert(buffer_.end(), data, data + n);
  std::size_t at = 0;
  bool keep = true;
  while (buffer_.size() - at >= kHeaderSize) {
    const unsigned char* m = buffer_.data() + at;
    const std::uint64_t body = BigEndian64(m + 42);
    const std::string name = Field(m + 14, 20);
    if (body > max_body_) {
      ++(*counters)[name].oversized;
      keep = false;
      at = buffer_.size();
      break;
    }
    if (buffer_.size() - at < kHeaderSize + body) break;
    last_name_ = name;
    Pose pose;
    if (TakeMessage(m, static_cast<std::size_t>(body), units_(name), &pose, &(*counters)[name])) {
      ++(pose.is_buttons ? (*counters)[name].buttons : (*counters)[name].messages);
      poses->push_back(std::move(pose));
    }
    at += kHeaderSize + static_cast<std::size_t>(body);
  }
  buffer_.erase(buffer_.begin(), buffer_.begin() + static_cast<std::ptrdiff_t>(at));
  return keep;
}

void IgtlStreamParser::Close(std::map<std::string, DeviceCounters>* counters) {
  if (!buffer_.empty()) {
    const std::string name = buffer_.size() >= 34 ? Field(buffer_.data() + 14, 20) : last_name_;
    ++(*counters)[name].truncated;
  }
  buffer_.clear();
}

namespace {
}  // namespace

void ParseListenAddress(const std::string& text, IgtlServerOptions* options) {
  std::string address = options->address, port = text;
  const auto colon = text.rfind(':');
  if (colon != std::string::npos) {
    address = text.substr(0, colon);
    port = text.substr(colon + 1);
  }
  std::size_t used = 0;
  long p = -1;
  try {
    p = std::stol(port, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  TROCAR_THROW_UNLESS(used == port.size() && p >= 0 && p <= 65535 && !address.empty(),
                      "listen address '" << text << "': expected [ADDRESS:]PORT, PORT in 0..65535");
  in_addr a{};
  TROCAR_THROW_UNLESS(::inet_pton(AF_INET, address.c_str(), &a) == 1,
                      "listen address '" << text << "': '" << address << "' is not an IPv4 address");
  options->address = address;
  options->port = static_cast<int>(p);
}

struct IgtlDeviceServer::Impl {
  IgtlServerOptions options;
  int listen_fd = -1;
  int port = 0;
  int wake[2] = {-1, -1};  ///< a pipe: another thread queued a message
  std::atomic<bool> stop{false};
  std::thread thread;

  struct Device {
    DeviceSample sample;
    std::uint64_t sequence = 0;
    std::chrono::steady_clock::time_point arrival;
    int connection = -1;  ///< the connection it last spoke on
    bool clutch = false, present = true;
    std::uint32_t pressed = 0;
    bool has_pose = false;
    std::chrono::steady_clock::time_point last_heard;
  };
  mutable std::mutex mutex;
  std::map<std::string, Device> devices;
  std::map<std::string, DeviceCounters> counters;
  std::string first;  ///< the first device with a valid pose
  int next_connection_id = 0;
  int open_connections = 0;
  struct Outgoing {
    int connection = -1;  ///< -1: every connection
    std::string device;   ///< whose counters (unicast)
    std::string bytes;
  };
  std::vector<Outgoing> outbox;  ///< under `mutex`
  long broadcast_sent = 0, broadcast_drops = 0;

  struct Connection {
    int fd = -1;
    int id = 0;
    std::unique_ptr<IgtlStreamParser> parser;
    std::string pending;  ///< bytes queued to send
    std::chrono::steady_clock::time_point accepted;
    bool proved = false;  ///< has sent a valid pose or buttons message
    std::uint32_t peer = 0;  ///< the peer's IPv4 address (network order)
  };
  std::vector<Connection> connections;

  /// New bytes of a connection: its poses taken, its drops counted. False: close it.
  bool Feed(Connection& c, const unsigned char* data, std::size_t n) {
    std::vector<IgtlStreamParser::Pose> poses;
    std::lock_guard<std::mutex> lock(mutex);
    const bool keep = c.parser->Feed(data, n, &poses, &counters);
    if (!poses.empty()) c.proved = true;
    const auto now = std::chrono::steady_clock::now();
    for (auto& pose : poses) {
      Device& d = devices[pose.device];
      if (d.connection != c.id) {
        // Another connection owns this name while it is open and speaking: not taken.
        const bool owner_open = std::any_of(connections.begin(), connections.end(), [&](const Connection& o) {
          return o.id == d.connection && o.fd >= 0;
        });
        if (owner_open && now - d.last_heard < std::chrono::seconds(1)) {
          ++counters[pose.device].name_in_use;
          --(pose.is_buttons ? counters[pose.device].buttons : counters[pose.device].messages);
          continue;
        }
        ++counters[pose.device].connections;
      }
      d.connection = c.id;
      d.last_heard = now;
      if (pose.is_buttons) {
        d.clutch = pose.clutch;
        d.present = pose.present;
        d.pressed = pose.pressed;
        continue;
      }
      d.sample.X_DH = pose.X_DH;
      d.arrival = now;
      d.has_pose = true;
      ++d.sequence;
      if (first.empty()) first = pose.device;
    }
    return keep;
  }

  /// Appends a whole message to a connection's queue, or drops it whole. True when queued.
  bool Queue(Connection& c, const std::string& bytes) {
    if (c.pending.size() + bytes.size() > options.max_pending) return false;
    c.pending += bytes;
    return true;
  }

  /// Takes the other threads' messages into the connections' queues.
  void TakeOutbox() {
    std::vector<Outgoing> out;
    {
      std::lock_guard<std::mutex> lock(mutex);
      out.swap(outbox);
      for (Outgoing& o : out) {
        if (o.connection < 0) {
          bool all = true;
          for (Connection& c : connections) all = Queue(c, o.bytes) && all;
          ++(all ? broadcast_sent : broadcast_drops);
          continue;
        }
        bool queued = false;
        for (Connection& c : connections)
          if (c.id == o.connection) queued = Queue(c, o.bytes);
        ++(queued ? counters[o.device].sent : counters[o.device].send_drops);
      }
    }
    char drain[256];
    while (::read(wake[0], drain, sizeof(drain)) > 0) {
    }
  }

  /// Sends what the socket takes now. False: the connection is gone.
  static bool Flush(Connection& c) {
    while (!c.pending.empty()) {
      const ssize_t n = ::send(c.fd, c.pending.data(), c.pending.size(), MSG_NOSIGNAL | MSG_DONTWAIT);
      if (n > 0) {
        c.pending.erase(0, static_cast<std::size_t>(n));
      } else if (n < 0 && (errno == EAGAIN || errno == EWOULDBLOCK || errno == EINTR)) {
        return true;
      } else {
        return false;
      }
    }
    return true;
  }

  void Close(Connection& c) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      c.parser->Close(&counters);
      --open_connections;
    }
    ::close(c.fd);
    c.fd = -1;
  }

  void Run() {
    std::vector<unsigned char> chunk(1 << 16);
    while (!stop.load()) {
      TakeOutbox();
      std::vector<pollfd> fds;
      fds.push_back({listen_fd, POLLIN, 0});
      fds.push_back({wake[0], POLLIN, 0});
      for (const Connection& c : connections)
        fds.push_back({c.fd, static_cast<short>(POLLIN | (c.pending.empty() ? 0 : POLLOUT)), 0});
      const int n = ::poll(fds.data(), fds.size(), 20);
      if (n <= 0) continue;
      if (fds[0].revents & POLLIN) {
        sockaddr_in from{};
        socklen_t from_size = sizeof(from);
        const int fd = ::accept(listen_fd, reinterpret_cast<sockaddr*>(&from), &from_size);
        if (fd >= 0) {
          const std::uint32_t peer = from.sin_addr.s_addr;
          // One address's connections that have not spoken yet: past its limit, its own oldest
          // gives its slot.
          auto unproved_from = [&](std::uint32_t address) {
            return static_cast<int>(std::count_if(connections.begin(), connections.end(),
                                                  [&](const Connection& c) {
                                                    return c.fd >= 0 && !c.proved && c.peer == address;
                                                  }));
          };
          if (unproved_from(peer) >= options.max_unproved_per_address) {
            Connection* oldest = nullptr;
            for (Connection& c : connections)
              if (c.fd >= 0 && !c.proved && c.peer == peer && (!oldest || c.accepted < oldest->accepted))
                oldest = &c;
            if (oldest) Close(*oldest);
          }
          if (static_cast<int>(std::count_if(connections.begin(), connections.end(), [](const Connection& c) {
                return c.fd >= 0;
              })) >= options.max_connections) {
            // Full: a connection that has not proved itself a device gives its slot: the oldest
            // of the address holding the most such connections.
            Connection* oldest = nullptr;
            int most = 0;
            for (Connection& c : connections) {
              if (c.fd < 0 || c.proved) continue;
              const int n = unproved_from(c.peer);
              if (!oldest || n > most || (n == most && c.accepted < oldest->accepted)) {
                oldest = &c;
                most = n;
              }
            }
            if (oldest) Close(*oldest);
          }
          if (static_cast<int>(std::count_if(connections.begin(), connections.end(), [](const Connection& c) {
                return c.fd >= 0;
              })) >= options.max_connections) {
            ::close(fd);
          } else {
            ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) | O_NONBLOCK);
            const int one = 1;
            ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
            Connection c;
            c.fd = fd;
            c.id = next_connection_id++;
            c.accepted = std::chrono::steady_clock::now();
            c.peer = peer;
            c.parser = std::make_unique<IgtlStreamParser>(options.max_body, [this](const std::string& name) {
              return options.units.count(name) ? options.units.at(name) : options.default_units;
            });
            connections.push_back(std::move(c));
            std::lock_guard<std::mutex> lock(mutex);
            ++open_connections;
          }
        }
      }
      // Only the connections this poll watched: one accepted just now is read on the next.
      const std::size_t polled = fds.size() - 2;
      for (std::size_t i = 0; i < polled && i < connections.size(); ++i) {
        const short events = fds[i + 2].revents;
        if (!events) continue;
        Connection& c = connections[i];
        if (c.fd < 0) continue;  // gave its slot to a new connection just now
        bool open = true;
        if (events & POLLOUT) open = Flush(c);
        // Read what is there, never more than one message's bound beyond a header.
        while (open && (events & (POLLIN | POLLHUP | POLLERR))) {
          const ssize_t got = ::recv(c.fd, chunk.data(), chunk.size(), 0);
          if (got > 0) {
            open = Feed(c, chunk.data(), static_cast<std::size_t>(got));
            if (got < static_cast<ssize_t>(chunk.size())) break;
          } else if (got == 0) {
            open = false;
          } else {
            if (errno != EAGAIN && errno != EWOULDBLOCK && errno != EINTR) open = false;
            break;
          }
        }
        if (!open) Close(c);
      }
      // Queued messages go out now rather than at the next poll.
      for (Connection& c : connections)
        if (c.fd >= 0 && !c.pending.empty() && !Flush(c)) Close(c);
      // Connections that have sent nothing valid for the idle timeout are closed.
      const auto now = std::chrono::steady_clock::now();
      for (Connection& c : connections)
        if (c.fd >= 0 && !c.proved &&
            std::chrono::duration<double>(now - c.accepted).count() > options.idle_timeout_s)
          Close(c);
      connections.erase(std::remove_if(connections.begin(), connections.end(),
                                       [](const Connection& c) { return c.fd < 0; }),
                        connections.end());
    }
    for (Connection& c : connections) ::close(c.fd);
  }

  void Wake() {
    const char one = 1;
    [[maybe_unused]] const ssize_t n = ::write(wake[1], &one, 1);  // full pipe: already woken
  }
};

IgtlDeviceServer::IgtlDeviceServer(const IgtlServerOptions& options) : impl_(std::make_unique<Impl>()) {
  impl_->options = options;
  TROCAR_THROW_UNLESS(options.max_body >= 48 && options.max_connections >= 1,
                      "device server: a body bound of at least 48 bytes and one connection");
  TROCAR_THROW_UNLESS(options.max_unproved_per_address >= 1,
                      "device server: " << options.max_unproved_per_address
                                        << " connections per address: expected at least 1");
  TROCAR_THROW_UNLESS(std::isfinite(options.idle_timeout_s) && options.idle_timeout_s > 0 &&
                          options.idle_timeout_s <= 3600,
                      "device server: idle timeout " << options.idle_timeout_s
                                                     << " s: expected 0 < s <= 3600");
  const std::string where = options.address + ":" + std::to_string(options.port);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(options.port));
  TROCAR_THROW_UNLESS(::inet_pton(AF_INET, options.address.c_str(), &addr.sin_addr) == 1,
                      where << ": not an IPv4 address");
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  TROCAR_THROW_UNLESS(fd >= 0, where << ": cannot open a socket: " << std::strerror(errno));
  const int one = 1;
  ::setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof(one));
  if (::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) != 0 || ::listen(fd, 8) != 0) {
    const int e = errno;
    ::close(fd);
    TROCAR_THROW(where << ": cannot listen: "
                       << (e == EADDRINUSE ? "the port is already in use (another trocar is listening, or listen on another port)"
                                           : std::strerror(e)));
  }
  ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) | O_NONBLOCK);
  if (::pipe(impl_->wake) != 0) {
    ::close(fd);
    TROCAR_THROW(where << ": cannot make the server's wake-up pipe: " << std::strerror(errno));
  }
  for (int end : impl_->wake) ::fcntl(end, F_SETFL, ::fcntl(end, F_GETFL) | O_NONBLOCK);
  socklen_t len = sizeof(addr);
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  impl_->listen_fd = fd;
  impl_->port = ntohs(addr.sin_port);
  impl_->thread = std::thread([this] { impl_->Run(); });
}

IgtlDeviceServer::~IgtlDeviceServer() {
  impl_->stop = true;
  impl_->Wake();
  if (impl_->thread.joinable()) impl_->thread.join();
  ::close(impl_->listen_fd);
  ::close(impl_->wake[0]);
  ::close(impl_->wake[1]);
}

int IgtlDeviceServer::port() const { return impl_->port; }
const std::string& IgtlDeviceServer::address() const { return impl_->options.address; }

bool IgtlDeviceServer::Latest(const std::string& device, DeviceSample* sample, std::uint64_t* sequence,
                              std::chrono::steady_clock::time_point* arrival, std::string* name) const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  const std::string& key = device.empty() ? impl_->first : device;
  auto it = impl_->devices.find(key);
  if (key.empty() && device.empty() && impl_->first.empty()) return false;
  if (it == impl_->devices.end() || !it->second.has_pose) return false;
  *sample = it->second.sample;
  sample->clutch = it->second.clutch;
  sample->operator_present = it->second.present;
  *sequence = it->second.sequence;
  *arrival = it->second.arrival;
  if (name) *name = it->first;
  return true;
}

std::map<std::string, DeviceCounters> IgtlDeviceServer::Counters() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->counters;
}

bool IgtlDeviceServer::Buttons(const std::string& device, bool* clutch, bool* present,
                               std::uint32_t* pressed) const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  auto it = impl_->devices.find(device.empty() ? impl_->first : device);
  if (it == impl_->devices.end()) return false;
  *clutch = it->second.clutch;
  *present = it->second.present;
  if (pressed) *pressed = it->second.pressed;
  return true;
}

bool IgtlDeviceServer::Send(const std::string& device, std::string message) {
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    auto it = impl_->devices.find(device.empty() ? impl_->first : device);
    if (it == impl_->devices.end() || it->second.connection < 0) return false;
    // A queue already long (the server thread is not keeping up): dropped, counted.
    if (impl_->outbox.size() > 4096) {
      ++impl_->counters[it->first].send_drops;
      return false;
    }
    impl_->outbox.push_back({it->second.connection, it->first, std::move(message)});
  }
  impl_->Wake();
  return true;
}

void IgtlDeviceServer::Broadcast(std::string message) {
  {
    std::lock_guard<std::mutex> lock(impl_->mutex);
    if (impl_->open_connections == 0) return;
    if (impl_->outbox.size() > 4096) {
      ++impl_->broadcast_drops;
      return;
    }
    impl_->outbox.push_back({-1, "", std::move(message)});
  }
  impl_->Wake();
}

long IgtlDeviceServer::broadcast_sent() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->broadcast_sent;
}
long IgtlDeviceServer::broadcast_drops() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->broadcast_drops;
}
int IgtlDeviceServer::connections() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->open_connections;
}

NetworkDeviceInput::NetworkDeviceInput(const IgtlDeviceServer* server, std::string device, double silence)
    : server_(server), device_(std::move(device)), silence_(silence) {
  latencies_.reserve(1 << 16);
}

std::string NetworkDeviceInput::name() const {
  return "OpenIGTLink " + server_->address() + ":" + std::to_string(server_->port()) +
         (device_.empty() ? " (first device)" : " device " + device_);
}

DeviceSample NetworkDeviceInput::Sample(double t) {
  DeviceSample s;
  std::uint64_t sequence = 0;
  std::chrono::steady_clock::time_point arrival;
  const auto now = std::chrono::steady_clock::now();
  const bool any = server_->Latest(device_, &s, &sequence, &arrival);
  s.t = t;
  const bool silent = !any || std::chrono::duration<double>(now - arrival).count() > silence_;
  if (silent) {
    if (!silent_) ++silences_;
    silent_ = true;
    silent_now_.store(true, std::memory_order_relaxed);
    s.operator_present = false;  // the arm holds; it re-anchors when the device speaks again
    return s;
  }
  silent_ = false;
  silent_now_.store(false, std::memory_order_relaxed);
  if (sequence != last_sequence_) {
    const double latency = std::chrono::duration<double>(now - arrival).count();
    last_latency_.store(latency, std::memory_order_relaxed);
    if (latencies_.size() < latencies_.capacity()) latencies_.push_back(latency);
    last_sequence_ = sequence;
  }
  return s;
}

IgtlDeviceClient::IgtlDeviceClient(const std::string& address, int port, double timeout) {
  const std::string where = address + ":" + std::to_string(port);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(static_cast<std::uint16_t>(port));
  TROCAR_THROW_UNLESS(port > 0 && port <= 65535 && ::inet_pton(AF_INET, address.c_str(), &addr.sin_addr) == 1,
                      where << ": not an IPv4 address and port");
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::duration<double>(timeout);
  while (true) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    TROCAR_THROW_UNLESS(fd_ >= 0, where << ": cannot open a socket: " << std::strerror(errno));
    if (::connect(fd_, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) == 0) break;
    const int e = errno;
    ::close(fd_);
    fd_ = -1;
    TROCAR_THROW_UNLESS(std::chrono::steady_clock::now() < deadline,
                        where << ": cannot connect: " << std::strerror(e));
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
  const int one = 1;
  ::setsockopt(fd_, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
}

IgtlDeviceClient::~IgtlDeviceClient() {
  if (fd_ >= 0) ::close(fd_);
}

bool IgtlDeviceClient::SendBytes(const std::string& bytes) {
  std::size_t sent = 0;
  while (sent < bytes.size()) {
    const ssize_t n = ::send(fd_, bytes.data() + sent, bytes.size() - sent, MSG_NOSIGNAL);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return false;
    sent += static_cast<std::size_t>(n);
  }
  return true;
}

std::string IgtlTransformMessage(const std::string& device, const Eigen::Isometry3d& X, double units) {
  igtl::TransformMessage::Pointer m = igtl::TransformMessage::New();
  m->SetDeviceName(device.c_str());
  igtl::Matrix4x4 matrix;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) matrix[r][c] = static_cast<float>(X.matrix()(r, c));
  for (int r = 0; r < 3; ++r) matrix[r][3] = static_cast<float>(X.translation()[r] / units);
  m->SetMatrix(matrix);
  igtl::TimeStamp::Pointer ts = igtl::TimeStamp::New();
  ts->GetTime();
  m->SetTimeStamp(ts);
  m->Pack();
  return std::string(static_cast<const char*>(m->GetPackPointer()), static_cast<std::size_t>(m->GetPackSize()));
}

std::string IgtlSensorMessage(const std::string& device, const std::vector<double>& values, std::uint64_t unit) {
  TROCAR_THROW_UNLESS(!values.empty() && values.size() <= 255, "SENSOR message: 1 to 255 values, not " << values.size());
  igtl::SensorMessage::Pointer m = igtl::SensorMessage::New();
  m->SetDeviceName(device.c_str());
  m->SetLength(static_cast<unsigned>(values.size()));
  m->SetUnit(unit);
  for (std::size_t i = 0; i < values.size(); ++i) m->SetValue(static_cast<unsigned>(i), values[i]);
  igtl::TimeStamp::Pointer ts = igtl::TimeStamp::New();
  ts->GetTime();
  m->SetTimeStamp(ts);
  m->Pack();
  return std::string(static_cast<const char*>(m->GetPackPointer()), static_cast<std::size_t>(m->GetPackSize()));
}

std::uint64_t IgtlNewtonUnit() {
  igtl::Unit::Pointer unit = igtl::Unit::New();
  unit->SetPrefix(igtl::Unit::SI_PREFIX_NONE);
  unit->Append(igtl::Unit::SI_DERIVED_NEWTON, 1);
  return unit->Pack();
}

bool IgtlDeviceClient::SendPose(const std::string& device, const Eigen::Isometry3d& X_DH, double units) {
  return SendBytes(IgtlTransformMessage(device, X_DH, units));
}

bool IgtlDeviceClient::SendButtons(const std::string& device, bool clutch, bool present, const std::vector<bool>& others) {
  std::vector<double> values = {clutch ? 1.0 : 0.0, present ? 1.0 : 0.0};
  for (bool b : others) values.push_back(b ? 1.0 : 0.0);
  return SendBytes(IgtlSensorMessage(device, values));
}

const std::map<std::string, long>& IgtlDeviceClient::Received() {
  unsigned char chunk[4096];
  while (true) {
    const ssize_t n = ::recv(fd_, chunk, sizeof(chunk), MSG_DONTWAIT);
    if (n <= 0) break;
    buffer_.insert(buffer_.end(), chunk, chunk + n);
    if (buffer_.size() > (1u << 20)) buffer_.clear();  // a server this client does not follow
  }
  std::size_t at = 0;
  while (buffer_.size() - at >= kHeaderSize) {
    const unsigned char* m = buffer_.data() + at;
    const std::uint64_t body = BigEndian64(m + 42);
    if (body > (1u << 16)) {
      buffer_.clear();
      at = 0;
      break;
    }
    if (buffer_.size() - at < kHeaderSize + body) break;
    const std::string type = Field(m + 2, 12), name = Field(m + 14, 20);
    const igtl::MessageHeader::Pointer header = UnpackHeader(m);
    // Each type's exact size before libopenigtlink reads it (its unpackers trust the count).
    if (type == "SENSOR") {
      const bool sized = body >= 10 && body == 10 + 8 * static_cast<std::uint64_t>(m[kHeaderSize]);
      const igtl::SensorMessage::Pointer sm =
          sized ? UnpackBody<igtl::SensorMessage>(header, m, body) : igtl::SensorMessage::Pointer();
      if (sm.IsNull()) {
        ++received_["SENSOR bad (size or CRC)"];
      } else {
        std::vector<double> values(sm->GetLength());
        double squared = 0.0;
        for (unsigned i = 0; i < values.size(); ++i) {
          values[i] = sm->GetValue(i);
          if (i < 3) squared += values[i] * values[i];
        }
        if (sm->GetUnit() == IgtlNewtonUnit()) max_force_ = std::max(max_force_, std::sqrt(squared));
        sensors_[name] = {std::move(values), sm->GetUnit()};
        ++received_[type];
      }
    } else if (type == "TRANSFORM") {
      const igtl::TransformMessage::Pointer t =
          body == 48 ? UnpackBody<igtl::TransformMessage>(header, m, body) : igtl::TransformMessage::Pointer();
      if (t.IsNull()) {
        ++received_["TRANSFORM bad (size or CRC)"];
      } else {
        igtl::Matrix4x4 matrix;
        t->GetMatrix(matrix);
        Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
        for (int r = 0; r < 3; ++r) {
          for (int k = 0; k < 3; ++k) X.matrix()(r, k) = matrix[r][k];
          X.matrix()(r, 3) = matrix[r][3] * 0.001;
        }
        transforms_[name] = X;
        ++received_[type];
      }
    } else {
      ++received_[type];
    }
    at += kHeaderSize + static_cast<std::size_t>(body);
  }
  buffer_.erase(buffer_.begin(), buffer_.begin() + static_cast<std::ptrdiff_t>(at));
  return received_;
}

bool IgtlDeviceClient::LastSensor(const std::string& device, std::vector<double>* values, std::uint64_t* unit) const {
  auto it = sensors_.find(device);
  if (it == sensors_.end()) return false;
  *values = it->second.first;
  if (unit) *unit = it->second.second;
  return true;
}

bool IgtlDeviceClient::LastTransform(const std::string& name, Eigen::Isometry3d* X) const {
  auto it = transforms_.find(name);
  if (it == transforms_.end()) return false;
  *X = it->second;
  return true;
}

}  // namespace trocar::control
