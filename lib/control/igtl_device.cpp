#include "control/igtl_device.hpp"

#include <algorithm>
#include <atomic>
#include <cerrno>
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
#include <igtlTransformMessage.h>

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

/// One complete message (header and body in `m`): a pose, or a drop counted.
bool TakeMessage(const unsigned char* m, std::size_t body_size, double units, IgtlStreamParser::Pose* pose,
                 DeviceCounters* count) {
  const std::string type = Field(m + 2, 12);
  const bool transform = type == "TRANSFORM", position = type == "POSITION";
  if (!transform && !position) {
    ++count->unknown_type;
    return false;
  }
  if (m[0] != 0 || m[1] != 1 || (transform && body_size != 48) ||
      (position && body_size != 12 && body_size != 24 && body_size != 28)) {
    ++count->malformed;
    return false;
  }
  igtl::MessageHeader::Pointer header = igtl::MessageHeader::New();
  header->InitPack();
  std::memcpy(header->GetPackPointer(), m, kHeaderSize);
  header->Unpack();
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  if (transform) {
    igtl::TransformMessage::Pointer t = igtl::TransformMessage::New();
    t->SetMessageHeader(header);
    t->AllocatePack();
    std::memcpy(t->GetPackBodyPointer(), m + kHeaderSize, body_size);
    if (!(t->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) {
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
    igtl::PositionMessage::Pointer pm = igtl::PositionMessage::New();
    pm->SetMessageHeader(header);
    pm->AllocatePack();
    std::memcpy(pm->GetPackBodyPointer(), m + kHeaderSize, body_size);
    if (!(pm->Unpack(1) & igtl::MessageHeader::UNPACK_BODY)) {
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
      ++(*counters)[name].messages;
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
  std::atomic<bool> stop{false};
  std::thread thread;

  struct Device {
    DeviceSample sample;
    std::uint64_t sequence = 0;
    std::chrono::steady_clock::time_point arrival;
    int connection = -1;  ///< the connection it last spoke on
  };
  mutable std::mutex mutex;
  std::map<std::string, Device> devices;
  std::map<std::string, DeviceCounters> counters;
  std::string first;  ///< the first device with a valid pose
  int next_connection_id = 0;

  struct Connection {
    int fd = -1;
    int id = 0;
    std::unique_ptr<IgtlStreamParser> parser;
  };
  std::vector<Connection> connections;


  /// New bytes of a connection: its poses taken, its drops counted. False: close it.
  bool Feed(Connection& c, const unsigned char* data, std::size_t n) {
    std::vector<IgtlStreamParser::Pose> poses;
    std::lock_guard<std::mutex> lock(mutex);
    const bool keep = c.parser->Feed(data, n, &poses, &counters);
    const auto now = std::chrono::steady_clock::now();
    for (auto& pose : poses) {
      Device& d = devices[pose.device];
      if (d.connection != c.id) ++counters[pose.device].connections;
      d.sample.X_DH = pose.X_DH;
      d.sample.clutch = false;
      d.sample.operator_present = true;
      d.arrival = now;
      d.connection = c.id;
      ++d.sequence;
      if (first.empty()) first = pose.device;
    }
    return keep;
  }

  void Close(Connection& c) {
    {
      std::lock_guard<std::mutex> lock(mutex);
      c.parser->Close(&counters);
    }
    ::close(c.fd);
    c.fd = -1;
  }

  void Run() {
    std::vector<unsigned char> chunk(1 << 16);
    while (!stop.load()) {
      std::vector<pollfd> fds;
      fds.push_back({listen_fd, POLLIN, 0});
      for (const Connection& c : connections) fds.push_back({c.fd, POLLIN, 0});
      const int n = ::poll(fds.data(), fds.size(), 20);
      if (n <= 0) continue;
      if (fds[0].revents & POLLIN) {
        const int fd = ::accept(listen_fd, nullptr, nullptr);
        if (fd >= 0) {
          if (static_cast<int>(connections.size()) >= options.max_connections) {
            ::close(fd);
          } else {
            ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) | O_NONBLOCK);
            const int one = 1;
            ::setsockopt(fd, IPPROTO_TCP, TCP_NODELAY, &one, sizeof(one));
            Connection c;
            c.fd = fd;
            c.id = next_connection_id++;
            c.parser = std::make_unique<IgtlStreamParser>(options.max_body, [this](const std::string& name) {
              return options.units.count(name) ? options.units.at(name) : options.default_units;
            });
            connections.push_back(std::move(c));
          }
        }
      }
      // Only the connections this poll watched: one accepted just now is read on the next.
      const std::size_t polled = fds.size() - 1;
      for (std::size_t i = 0; i < polled && i < connections.size(); ++i) {
        const short events = fds[i + 1].revents;
        if (!events) continue;
        Connection& c = connections[i];
        bool open = true;
        // Read what is there, never more than one message's bound beyond a header.
        while (open) {
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
      connections.erase(std::remove_if(connections.begin(), connections.end(),
                                       [](const Connection& c) { return c.fd < 0; }),
                        connections.end());
    }
    for (Connection& c : connections) ::close(c.fd);
  }
};

IgtlDeviceServer::IgtlDeviceServer(const IgtlServerOptions& options) : impl_(std::make_unique<Impl>()) {
  impl_->options = options;
  TROCAR_THROW_UNLESS(options.max_body >= 48 && options.max_connections >= 1,
                      "device server: a body bound of at least 48 bytes and one connection");
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
                       << (e == EADDRINUSE ? "the port is already in use (another trocar, or give another --listen port)"
                                           : std::strerror(e)));
  }
  ::fcntl(fd, F_SETFL, ::fcntl(fd, F_GETFL) | O_NONBLOCK);
  socklen_t len = sizeof(addr);
  ::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len);
  impl_->listen_fd = fd;
  impl_->port = ntohs(addr.sin_port);
  impl_->thread = std::thread([this] { impl_->Run(); });
}

IgtlDeviceServer::~IgtlDeviceServer() {
  impl_->stop = true;
  if (impl_->thread.joinable()) impl_->thread.join();
  ::close(impl_->listen_fd);
}

int IgtlDeviceServer::port() const { return impl_->port; }
const std::string& IgtlDeviceServer::address() const { return impl_->options.address; }

bool IgtlDeviceServer::Latest(const std::string& device, DeviceSample* sample, std::uint64_t* sequence,
                              std::chrono::steady_clock::time_point* arrival, std::string* name) const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  const std::string& key = device.empty() ? impl_->first : device;
  auto it = impl_->devices.find(key);
  if (key.empty() && device.empty() && impl_->first.empty()) return false;
  if (it == impl_->devices.end()) return false;
  *sample = it->second.sample;
  *sequence = it->second.sequence;
  *arrival = it->second.arrival;
  if (name) *name = it->first;
  return true;
}

std::map<std::string, DeviceCounters> IgtlDeviceServer::Counters() const {
  std::lock_guard<std::mutex> lock(impl_->mutex);
  return impl_->counters;
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
    s.operator_present = false;  // the arm holds; it re-anchors when the device speaks again
    return s;
  }
  silent_ = false;
  if (sequence != last_sequence_) {
    if (latencies_.size() < latencies_.capacity()) latencies_.push_back(std::chrono::duration<double>(now - arrival).count());
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

bool IgtlDeviceClient::SendPose(const std::string& device, const Eigen::Isometry3d& X_DH, double units) {
  igtl::TransformMessage::Pointer m = igtl::TransformMessage::New();
  m->SetDeviceName(device.c_str());
  igtl::Matrix4x4 matrix;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) matrix[r][c] = static_cast<float>(X_DH.matrix()(r, c));
  for (int r = 0; r < 3; ++r) matrix[r][3] = static_cast<float>(X_DH.translation()[r] / units);
  m->SetMatrix(matrix);
  igtl::TimeStamp::Pointer ts = igtl::TimeStamp::New();
  ts->GetTime();
  m->SetTimeStamp(ts);
  m->Pack();
  return SendBytes(std::string(static_cast<const char*>(m->GetPackPointer()), static_cast<std::size_t>(m->GetPackSize())));
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
    const std::uint64_t body = BigEndian64(buffer_.data() + at + 42);
    if (body > (1u << 16)) {
      buffer_.clear();
      at = 0;
      break;
    }
    if (buffer_.size() - at < kHeaderSize + body) break;
    ++received_[Field(buffer_.data() + at + 2, 12)];
    at += kHeaderSize + static_cast<std::size_t>(body);
  }
  buffer_.erase(buffer_.begin(), buffer_.begin() + static_cast<std::ptrdiff_t>(at));
  return received_;
}

}  // namespace trocar::control
