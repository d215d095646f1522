// The OpenIGTLink device server against a client written here from the protocol description
// (not through libopenigtlink): header, big-endian fields, CRC-64 (ECMA-182), TRANSFORM and
// POSITION bodies; and every fault the issue lists, injected byte by byte.
#include "control/igtl_device.hpp"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <memory>
#include <random>
#include <thread>

#include <gtest/gtest.h>

#include "common/error.hpp"
#include "control/control_loop.hpp"
#include "control/teleop_session.hpp"
#include "robot/load_robot.hpp"
#include "test_util.hpp"

namespace trocar::control {
namespace {

/// CRC-64 ECMA-182 as OpenIGTLink uses it: polynomial 0x42F0E1EBA9EA3693, initial 0, not
/// reflected, no final xor; bit by bit, from the definition.
std::uint64_t Crc64(const std::string& data) {
  std::uint64_t crc = 0;
  for (unsigned char byte : data) {
    crc ^= static_cast<std::uint64_t>(byte) << 56;
    for (int i = 0; i < 8; ++i) crc = (crc & (1ull << 63)) ? (crc << 1) ^ 0x42F0E1EBA9EA3693ull : crc << 1;
  }
  return crc;
}

void Put64(std::string* s, std::uint64_t v) {
  for (int i = 7; i >= 0; --i) s->push_back(static_cast<char>((v >> (8 * i)) & 0xff));
}
void PutFloat(std::string* s, float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  for (int i = 3; i >= 0; --i) s->push_back(static_cast<char>((u >> (8 * i)) & 0xff));
}
std::string Fixed(const std::string& text, std::size_t n) {
  std::string s = text.substr(0, n);
  s.resize(n, '\0');
  return s;
}

/// A whole message: 58-byte header (version 1) and the body.
std::string Message(const std::string& type, const std::string& name, const std::string& body,
                    std::uint64_t body_size_field = ~0ull, bool bad_crc = false) {
  std::string m;
  m.push_back(0);
  m.push_back(1);  // version 1
  m += Fixed(type, 12);
  m += Fixed(name, 20);
  Put64(&m, 0);  // timestamp
  Put64(&m, body_size_field == ~0ull ? body.size() : body_size_field);
  Put64(&m, Crc64(body) ^ (bad_crc ? 1 : 0));
  return m + body;
}

/// TRANSFORM body: the upper 3x4 of the matrix column by column, translation in mm.
std::string TransformBody(const Eigen::Isometry3d& X, double mm_per_unit = 1000) {
  std::string b;
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < 3; ++r) PutFloat(&b, static_cast<float>(X.linear()(r, c)));
  for (int r = 0; r < 3; ++r) PutFloat(&b, static_cast<float>(X.translation()[r] * mm_per_unit));
  return b;
}

class RawClient {
 public:
  /// `from`: the local address to connect from (another host on the loopback net, 127.x.y.z).
  explicit RawClient(int port, const char* from = nullptr) {
    fd_ = ::socket(AF_INET, SOCK_STREAM, 0);
    if (from) {
      sockaddr_in local{};
      local.sin_family = AF_INET;
      ::inet_pton(AF_INET, from, &local.sin_addr);
      EXPECT_EQ(::bind(fd_, reinterpret_cast<sockaddr*>(&local), sizeof(local)), 0) << from;
    }
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_port = htons(static_cast<std::uint16_t>(port));
    ::inet_pton(AF_INET, "127.0.0.1", &a.sin_addr);
    EXPECT_EQ(::connect(fd_, reinterpret_cast<sockaddr*>(&a), sizeof(a)), 0);
  }
  ~RawClient() { ::close(fd_); }
  /// The server closed this connection within `ms` milliseconds.
  bool ClosedWithin(int ms) {
    char c;
    for (int i = 0; i <= ms / 10; ++i) {
      const ssize_t n = ::recv(fd_, &c, 1, MSG_DONTWAIT);
      if (n == 0) return true;
      if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
  }
  /// The server closed this connection (the stream's end is read).
  bool Closed() {
    char c;
    for (int i = 0; i < 300; ++i) {
      const ssize_t n = ::recv(fd_, &c, 1, MSG_DONTWAIT);
      if (n == 0) return true;
      if (n < 0 && errno != EAGAIN && errno != EWOULDBLOCK) return true;  // reset
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
  }
  void Send(const std::string& bytes) { ASSERT_EQ(::send(fd_, bytes.data(), bytes.size(), MSG_NOSIGNAL), ssize_t(bytes.size())); }
  /// The next whole message (header and body), waiting up to 3 s; "" when none came.
  std::string ReadMessage() {
    for (int i = 0; i < 300; ++i) {
      char chunk[4096];
      const ssize_t n = ::recv(fd_, chunk, sizeof(chunk), MSG_DONTWAIT);
      if (n > 0) buffer_.append(chunk, static_cast<std::size_t>(n));
      if (buffer_.size() >= 58) {
        std::uint64_t size = 0;
        for (int k = 0; k < 8; ++k) size = (size << 8) | static_cast<unsigned char>(buffer_[42 + k]);
        if (buffer_.size() >= 58 + size) {
          std::string m = buffer_.substr(0, 58 + size);
          buffer_.erase(0, 58 + size);
          return m;
        }
      }
      if (n <= 0) std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return "";
  }

 private:
  int fd_;
  std::string buffer_;
};

/// Waits until `done` holds (the server runs in its own thread), at most 3 s.
template <typename F>
bool Eventually(F done) {
  for (int i = 0; i < 300; ++i) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  return done();
}

Eigen::Isometry3d RandomPose(std::mt19937* rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.linear() = Eigen::Quaterniond(u(*rng), u(*rng), u(*rng), u(*rng)).normalized().toRotationMatrix();
  X.translation() = Eigen::Vector3d(u(*rng), u(*rng), u(*rng)) * 0.2;
  return X;
}

std::uint64_t Get64(const std::string& s, std::size_t at) {
  std::uint64_t v = 0;
  for (int k = 0; k < 8; ++k) v = (v << 8) | static_cast<unsigned char>(s[at + k]);
  return v;
}
double GetDouble(const std::string& s, std::size_t at) {
  const std::uint64_t u = Get64(s, at);
  double d;
  std::memcpy(&d, &u, 8);
  return d;
}
void PutDouble(std::string* s, double d) {
  std::uint64_t u;
  std::memcpy(&u, &d, 8);
  Put64(s, u);
}
/// SENSOR body: count, status, unit (64 bits), then the float64 values.
std::string SensorBody(const std::vector<double>& values, std::uint64_t unit = 0, int count = -1) {
  std::string b;
  b.push_back(static_cast<char>(count >= 0 ? count : static_cast<int>(values.size())));
  b.push_back(0);
  Put64(&b, unit);
  for (double v : values) PutDouble(&b, v);
  return b;
}
/// igtl_unit.h by hand: 4 bits of prefix, then (6 bits unit, 4 bits exponent) per unit. Newton
/// is SI derived unit 0x0B; one unit, exponent 1, no prefix.
constexpr std::uint64_t kNewtonByHand = (0x0Bull << 54) | (1ull << 50);

IgtlServerOptions AnyPort() {
  IgtlServerOptions o;
  o.port = 0;
  return o;
}

TEST(IgtlDevice, AClientWrittenFromTheProtocolIsUnderstoodOverSeededPoses) {
  IgtlDeviceServer server(AnyPort());
  RawClient client(server.port());
  std::mt19937 rng(5);
  for (int i = 0; i < 40; ++i) {
    const Eigen::Isometry3d X = RandomPose(&rng);
    client.Send(Message("TRANSFORM", "hand", TransformBody(X)));
    DeviceSample s;
    std::uint64_t seq = 0;
    std::chrono::steady_clock::time_point at;
    ASSERT_TRUE(Eventually([&] { return server.Latest("hand", &s, &seq, &at) && seq == std::uint64_t(i + 1); })) << i;
    EXPECT_LT((s.X_DH.translation() - X.translation()).norm(), 1e-6) << i;  // mm -> m, float
    EXPECT_LT((s.X_DH.linear() - X.linear()).norm(), 1e-5) << i;
  }
  // POSITION: position and quaternion (x, y, z, w).
  const Eigen::Isometry3d X = RandomPose(&rng);
  const Eigen::Quaterniond q(X.linear());
  std::string body;
  for (int r = 0; r < 3; ++r) PutFloat(&body, static_cast<float>(X.translation()[r] * 1000));
  for (double v : {q.x(), q.y(), q.z(), q.w()}) PutFloat(&body, static_cast<float>(v));
  client.Send(Message("POSITION", "pen", body));
  DeviceSample s;
  std::uint64_t seq = 0;
  std::chrono::steady_clock::time_point at;
  ASSERT_TRUE(Eventually([&] { return server.Latest("pen", &s, &seq, &at); }));
  EXPECT_LT((s.X_DH.translation() - X.translation()).norm(), 1e-6);
  EXPECT_LT((s.X_DH.linear() - X.linear()).norm(), 1e-5);
  EXPECT_EQ(server.Counters().at("hand").messages, 40);
  EXPECT_EQ(server.Counters().at("hand").drops(), 0);
}

TEST(IgtlDevice, WhatLibopenigtlinkSendsDecodesHereWithItsCrc) {
  // A plain listener takes what IgtlDeviceClient (libopenigtlink's encoder) sends.
  const int listener = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  ::inet_pton(AF_INET, "127.0.0.1", &a.sin_addr);
  ASSERT_EQ(::bind(listener, reinterpret_cast<sockaddr*>(&a), sizeof(a)), 0);
  ASSERT_EQ(::listen(listener, 1), 0);
  socklen_t len = sizeof(a);
  ::getsockname(listener, reinterpret_cast<sockaddr*>(&a), &len);
  IgtlDeviceClient client("127.0.0.1", ntohs(a.sin_port));
  const int fd = ::accept(listener, nullptr, nullptr);
  std::mt19937 rng(9);
  for (int i = 0; i < 20; ++i) {
    const Eigen::Isometry3d X = RandomPose(&rng);
    ASSERT_TRUE(client.SendPose("stylus", X));
    std::string got(58 + 48, '\0');
    std::size_t n = 0;
    while (n < got.size()) {
      const ssize_t r = ::recv(fd, got.data() + n, got.size() - n, 0);
      ASSERT_GT(r, 0);
      n += static_cast<std::size_t>(r);
    }
    EXPECT_EQ(got.substr(2, 12), Fixed("TRANSFORM", 12));
    EXPECT_EQ(got.substr(14, 20), Fixed("stylus", 20));
    const std::string body = got.substr(58);
    std::uint64_t size = 0, crc = 0;
    for (int k = 0; k < 8; ++k) size = (size << 8) | static_cast<unsigned char>(got[42 + k]);
    for (int k = 0; k < 8; ++k) crc = (crc << 8) | static_cast<unsigned char>(got[50 + k]);
    EXPECT_EQ(size, 48u);
    EXPECT_EQ(crc, Crc64(body)) << "the CRC-64 of the two implementations differ";
    EXPECT_EQ(body, TransformBody(X)) << "the bodies differ";
  }
  ::close(fd);
  ::close(listener);
}

TEST(IgtlDevice, EveryFaultIsDroppedAndCountedAndTheDeviceGoesOn) {
  IgtlServerOptions o = AnyPort();
  o.max_body = 1024;
  IgtlDeviceServer server(o);
  const Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  auto taken = [&](long n) {
    return Eventually([&] { auto c = server.Counters(); return c.count("d") && c.at("d").messages == n; });
  };
  {
    RawClient c(server.port());
    c.Send(Message("TRANSFORM", "d", TransformBody(X)));
    ASSERT_TRUE(taken(1));
    c.Send(Message("TRANSFORM", "d", TransformBody(X), ~0ull, /*bad_crc=*/true));
    c.Send(Message("IMAGE", "d", std::string(200, 'x')));                      // unknown type, skipped
    c.Send(Message("TRANSFORM", "d", TransformBody(X).substr(0, 40)));         // wrong size for its type
    Eigen::Isometry3d nan = X;
    nan.translation().x() = NAN;
    c.Send(Message("TRANSFORM", "d", TransformBody(nan)));                     // non-finite
    c.Send(Message("TRANSFORM", "d", TransformBody(X)));                       // and a good one after them
    ASSERT_TRUE(taken(2));
    const auto d = server.Counters().at("d");
    EXPECT_EQ(d.crc, 1);
    EXPECT_EQ(d.unknown_type, 1);
    EXPECT_EQ(d.malformed, 1);
    EXPECT_EQ(d.non_finite, 1);
  }
  {
    // A body of a terabyte, claimed: nothing allocated for it, the connection closed.
    RawClient c(server.port());
    std::string huge = Message("TRANSFORM", "d", "", 1ull << 40);
    c.Send(huge);
    ASSERT_TRUE(Eventually([&] { return server.Counters().at("d").oversized == 1; }));
  }
  {
    // A message cut off by its connection closing.
    RawClient c(server.port());
    const std::string m = Message("TRANSFORM", "d", TransformBody(X));
    c.Send(m.substr(0, 70));
  }
  ASSERT_TRUE(Eventually([&] { return server.Counters().at("d").truncated == 1; }));
  // Garbage of every length: never a crash; a good message on a new connection is taken.
  std::mt19937 rng(3);
  for (int i = 0; i < 50; ++i) {
    RawClient c(server.port());
    std::string junk(std::uniform_int_distribution<int>(1, 300)(rng), '\0');
    for (char& ch : junk) ch = static_cast<char>(rng());
    c.Send(junk);
  }
  RawClient again(server.port());
  again.Send(Message("TRANSFORM", "d", TransformBody(X)));
  EXPECT_TRUE(taken(3));
  // Connections it sent whole messages on: the first and the last (a reconnect).
  EXPECT_EQ(server.Counters().at("d").connections, 2);
}

TEST(IgtlDevice, TwoDevicesAreKeptApartAndASilentOneHoldsThenResumes) {
  IgtlDeviceServer server(AnyPort());
  RawClient a(server.port()), b(server.port());
  Eigen::Isometry3d Xa = Eigen::Isometry3d::Identity(), Xb = Eigen::Isometry3d::Identity();
  Xa.translation() = Eigen::Vector3d(0.01, 0, 0);
  Xb.translation() = Eigen::Vector3d(0, 0.02, 0);
  a.Send(Message("TRANSFORM", "left", TransformBody(Xa)));
  b.Send(Message("TRANSFORM", "right", TransformBody(Xb)));
  NetworkDeviceInput left(&server, "left", 0.05), right(&server, "right", 0.05);
  ASSERT_TRUE(Eventually([&] { return left.Sample(0).operator_present && right.Sample(0).operator_present; }));
  EXPECT_LT((left.Sample(0).X_DH.translation() - Xa.translation()).norm(), 1e-6);
  EXPECT_LT((right.Sample(0).X_DH.translation() - Xb.translation()).norm(), 1e-6);
  // "left" goes silent: absent (the arm holds); "right" speaks on.
  for (int i = 0; i < 10; ++i) {
    b.Send(Message("TRANSFORM", "right", TransformBody(Xb)));
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  EXPECT_FALSE(left.Sample(1).operator_present);
  EXPECT_TRUE(right.Sample(1).operator_present);
  EXPECT_EQ(left.silences(), 1);
  a.Send(Message("TRANSFORM", "left", TransformBody(Xa)));
  EXPECT_TRUE(Eventually([&] { return left.Sample(2).operator_present; }));
  EXPECT_FALSE(left.latencies().empty());
}

TEST(IgtlDevice, TheServersSensorAndTransformMessagesDecodeInAClientWrittenFromTheProtocol) {
  EXPECT_EQ(IgtlNewtonUnit(), kNewtonByHand) << "the unit codes of the two implementations differ";
  IgtlDeviceServer server(AnyPort());
  RawClient client(server.port());
  client.Send(Message("TRANSFORM", "hand", TransformBody(Eigen::Isometry3d::Identity())));
  DeviceSample s;
  std::uint64_t seq = 0;
  std::chrono::steady_clock::time_point at;
  ASSERT_TRUE(Eventually([&] { return server.Latest("hand", &s, &seq, &at); }));
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-4, 4);
  for (int i = 0; i < 20; ++i) {
    const std::vector<double> f = {u(rng), u(rng), u(rng)};
    ASSERT_TRUE(server.Send("hand", IgtlSensorMessage("hand", f, IgtlNewtonUnit())));
    const std::string m = client.ReadMessage();
    ASSERT_EQ(m.size(), 58u + 10 + 24) << i;
    EXPECT_EQ(m.substr(2, 12), Fixed("SENSOR", 12));
    EXPECT_EQ(m.substr(14, 20), Fixed("hand", 20));
    const std::string body = m.substr(58);
    EXPECT_EQ(Get64(m, 50), Crc64(body)) << "the CRC-64 of the two implementations differ";
    EXPECT_EQ(static_cast<unsigned char>(body[0]), 3);
    EXPECT_EQ(Get64(body, 2), kNewtonByHand);
    for (int k = 0; k < 3; ++k) EXPECT_EQ(GetDouble(body, 10 + 8 * k), f[k]) << i;
  }
  // A pose out to every connection (3D Slicer's way in): millimetres, our CRC.
  const Eigen::Isometry3d X = RandomPose(&rng);
  server.Broadcast(IgtlTransformMessage("psm1", X, 0.001));
  const std::string m = client.ReadMessage();
  ASSERT_EQ(m.size(), 58u + 48);
  EXPECT_EQ(m.substr(14, 20), Fixed("psm1", 20));
  EXPECT_EQ(Get64(m, 50), Crc64(m.substr(58)));
  EXPECT_EQ(m.substr(58), TransformBody(X));
  EXPECT_EQ(server.Counters().at("hand").sent, 20);
}

TEST(IgtlDevice, ButtonsFromTheDeviceSetClutchAndPresenceAndBadOnesAreCounted) {
  IgtlDeviceServer server(AnyPort());
  RawClient client(server.port());
  client.Send(Message("TRANSFORM", "hand", TransformBody(Eigen::Isometry3d::Identity())));
  NetworkDeviceInput input(&server, "hand", 1.0);
  ASSERT_TRUE(Eventually([&] { return input.Sample(0).operator_present; }));
  EXPECT_FALSE(input.Sample(0).clutch);
  client.Send(Message("SENSOR", "hand", SensorBody({1, 1, 0, 1})));  // clutch, present, 2 others
  ASSERT_TRUE(Eventually([&] { return input.Sample(0).clutch; }));
  bool clutch = false, present = false;
  std::uint32_t pressed = 0;
  ASSERT_TRUE(server.Buttons("hand", &clutch, &present, &pressed));
  EXPECT_EQ(pressed, 2u);  // the fourth value
  client.Send(Message("SENSOR", "hand", SensorBody({0, 0})));  // released, operator away
  ASSERT_TRUE(Eventually([&] { return !input.Sample(0).operator_present; }));
  EXPECT_FALSE(input.Sample(0).clutch);
  client.Send(Message("SENSOR", "hand", SensorBody({0, 1}, 0, 5)));  // says 5 values, has 2
  client.Send(Message("SENSOR", "hand", SensorBody({NAN, 1})));
  client.Send(Message("SENSOR", "hand", SensorBody({1, 1}), ~0ull, /*bad_crc=*/true));
  client.Send(Message("SENSOR", "hand", SensorBody({0, 1})));
  ASSERT_TRUE(Eventually([&] { return server.Counters().at("hand").buttons == 3; }));
  const auto c = server.Counters().at("hand");
  EXPECT_EQ(c.malformed, 1);
  EXPECT_EQ(c.non_finite, 1);
  EXPECT_EQ(c.crc, 1);
  EXPECT_TRUE(input.Sample(0).operator_present);
  EXPECT_FALSE(input.Sample(0).clutch);  // the bad clutch message was not taken
}

TEST(IgtlDevice, AClientThatDoesNotReadNeitherBlocksTheServerNorGrowsItsMemory) {
  IgtlServerOptions o = AnyPort();
  o.max_pending = 8192;
  IgtlDeviceServer server(o);
  RawClient deaf(server.port()), other(server.port());
  deaf.Send(Message("TRANSFORM", "deaf", TransformBody(Eigen::Isometry3d::Identity())));
  DeviceSample s;
  std::uint64_t seq = 0;
  std::chrono::steady_clock::time_point at;
  ASSERT_TRUE(Eventually([&] { return server.Latest("deaf", &s, &seq, &at); }));
  // Far more than the socket's buffers and the pending bound hold.
  const std::string big = IgtlSensorMessage("deaf", std::vector<double>(200, 1.0));
  for (int i = 0; i < 20000; ++i) server.Send("deaf", big);
  // The server still takes another device's poses at once.
  for (int i = 1; i <= 20; ++i) {
    other.Send(Message("TRANSFORM", "other", TransformBody(Eigen::Isometry3d::Identity())));
    ASSERT_TRUE(Eventually([&] { return server.Latest("other", &s, &seq, &at) && seq == std::uint64_t(i); })) << i;
  }
  ASSERT_TRUE(Eventually([&] {
    const auto c = server.Counters().at("deaf");
    return c.sent + c.send_drops == 20000;
  })) << "every message sent or dropped whole";
  const auto c = server.Counters().at("deaf");
  EXPECT_GT(c.sent, 0);
  EXPECT_GT(c.send_drops, 0);
}

// The faults injected into a running session: the arm holds through bad packets and a silence,
// and resumes from where it held when the device comes back on a new connection with its hand
// elsewhere (a re-anchor, not a jump).
TEST(IgtlDevice, ASessionHoldsThroughFaultsAndSilenceAndResumesWithoutAJump) {
  IgtlDeviceServer server(AnyPort());
  const auto model = robot::LoadRobot(test::SourcePath("robots/davinci-classic/psm.yaml"));
  control::ControlLoop loop(model, control::MakeController("dls", model, control::Vector6d::Constant(20)),
                            model.defaults().home);
  NetworkDeviceInput input(&server, "d", 0.05);
  auto pose = [](double x, double y) {
    Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
    X.translation() = Eigen::Vector3d(x, y, 0);
    return X;
  };
  std::atomic<bool> started{false};
  std::thread device([&] {
    {
      RawClient c(server.port());
      for (int i = 0; i < 400; ++i) {  // 0.4 s moving along x
        c.Send(Message("TRANSFORM", "d", TransformBody(pose(0.02 * i / 400.0, 0))));
        started = true;
        std::this_thread::sleep_for(std::chrono::milliseconds(1));
      }
      c.Send(Message("TRANSFORM", "d", TransformBody(pose(0.5, 0)), ~0ull, true));  // bad CRC
      Eigen::Isometry3d nan = pose(0, 0);
      nan.translation().y() = NAN;
      c.Send(Message("TRANSFORM", "d", TransformBody(nan)));
      c.Send(Message("STRING", "d", std::string(30, 'x')));
      c.Send(Message("TRANSFORM", "d", TransformBody(pose(0.5, 0))).substr(0, 80));  // cut by the close
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(300));  // silent
    RawClient again(server.port());
    for (int i = 0; i < 800; ++i) {  // back, the hand 5 cm away, moving along x again
      again.Send(Message("TRANSFORM", "d", TransformBody(pose(0.02 + 0.02 * i / 400.0, 0.05))));
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  });
  while (!started) std::this_thread::sleep_for(std::chrono::milliseconds(1));
  TeleopSessionOptions options;
  // The device's 0.4 s, faults, 0.3 s of silence, then on past the session's end (room for a
  // loaded machine's slow sleeps).
  options.duration = 1.2;
  options.realtime = true;
  const Recorder record = RunTeleopSession(&loop, &input, options);
  device.join();
  const auto& rows = record.rows();
  long absent = 0, following_after = 0;
  double largest_step = 0.0;
  for (std::size_t i = 1; i < rows.size(); ++i) {
    largest_step = std::max(largest_step, (rows[i].X_WD.translation() - rows[i - 1].X_WD.translation()).norm());
    if (rows[i].status == SampleStatus::kHeldAbsent) {
      ++absent;
      EXPECT_LT((rows[i].X_WD.translation() - rows[i - 1].X_WD.translation()).norm(), 1e-12) << "moved while silent";
    } else if (absent > 0 && rows[i].status == SampleStatus::kFollowing) {
      ++following_after;
    }
  }
  EXPECT_GT(absent, 150) << "the silence was not taken as absence";
  EXPECT_GT(following_after, 100) << "teleoperation did not resume";
  EXPECT_LT(largest_step, 0.002) << "the desired pose jumped (the 5 cm the hand moved while away?)";
  const auto c = server.Counters().at("d");
  EXPECT_EQ(c.crc, 1);
  EXPECT_EQ(c.non_finite, 1);
  EXPECT_EQ(c.unknown_type, 1);
  EXPECT_EQ(c.truncated, 1);
  EXPECT_EQ(c.connections, 2);
  EXPECT_EQ(input.silences(), 1);
}

TEST(IgtlDevice, ADeviceNameBelongsToOneConnectionSoNoOtherClientTakesTheArmOver) {
  IgtlDeviceServer server(AnyPort());
  Eigen::Isometry3d mine = Eigen::Isometry3d::Identity(), theirs = Eigen::Isometry3d::Identity();
  mine.translation() = Eigen::Vector3d(0.01, 0, 0);
  theirs.translation() = Eigen::Vector3d(0, 0.3, 0);
  DeviceSample s;
  std::uint64_t seq = 0;
  std::chrono::steady_clock::time_point at;
  auto holder = std::make_unique<RawClient>(server.port());
  holder->Send(Message("TRANSFORM", "left", TransformBody(mine)));
  ASSERT_TRUE(Eventually([&] { return server.Latest("left", &s, &seq, &at); }));
  RawClient intruder(server.port());
  for (int i = 0; i < 5; ++i) {
    intruder.Send(Message("TRANSFORM", "left", TransformBody(theirs)));
    intruder.Send(Message("SENSOR", "left", SensorBody({1, 1})));  // nor its clutch
  }
  ASSERT_TRUE(Eventually([&] { return server.Counters().at("left").name_in_use == 10; }));
  ASSERT_TRUE(server.Latest("left", &s, &seq, &at));
  EXPECT_LT((s.X_DH.translation() - mine.translation()).norm(), 1e-6) << "another client moved the arm";
  EXPECT_FALSE(s.clutch);
  EXPECT_EQ(server.Counters().at("left").messages, 1);
  // The owner goes: the name is free, and the other client's poses are taken.
  holder.reset();
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  intruder.Send(Message("TRANSFORM", "left", TransformBody(theirs)));
  ASSERT_TRUE(Eventually([&] {
    return server.Latest("left", &s, &seq, &at) && (s.X_DH.translation() - theirs.translation()).norm() < 1e-6;
  }));
  EXPECT_EQ(server.Counters().at("left").connections, 2);
}

// #44 item 6: connections that never send a valid message do not keep the slots from a device.
// Every slot taken by idle clients: a device still gets in (the oldest idle one gives its slot),
// idle clients are closed after the timeout, and a device that has spoken is never put out by
// the idle clients that come after it.
TEST(IgtlDevice, IdleConnectionsNeverKeepADeviceOut) {
  IgtlServerOptions options = AnyPort();
  options.max_connections = 4;
  options.idle_timeout_s = 0.5;
  IgtlDeviceServer server(options);
  std::vector<std::unique_ptr<RawClient>> idle;
  for (int i = 0; i < 4; ++i) idle.push_back(std::make_unique<RawClient>(server.port()));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  X.translation() = Eigen::Vector3d(0.02, 0, 0);
  RawClient device(server.port());
  DeviceSample s;
  std::uint64_t seq = 0;
  std::chrono::steady_clock::time_point at;
  device.Send(Message("TRANSFORM", "left", TransformBody(X)));
  ASSERT_TRUE(Eventually([&] { return server.Latest("left", &s, &seq, &at); }))
      << "the device was kept out by idle connections";
  // More idle clients than slots, past the timeout: the device keeps streaming and is heard.
  for (int i = 0; i < 8; ++i) idle.push_back(std::make_unique<RawClient>(server.port()));
  std::uint64_t last = seq;
  for (int k = 0; k < 10; ++k) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    device.Send(Message("TRANSFORM", "left", TransformBody(X)));
  }
  ASSERT_TRUE(Eventually([&] { return server.Latest("left", &s, &seq, &at) && seq > last; }));
  EXPECT_EQ(server.Counters().at("left").connections, 1) << "the device was put out and came back";
  // The idle ones were closed: each reads the end of its stream.
  int closed = 0;
  for (auto& c : idle) closed += c->Closed();
  EXPECT_EQ(closed, static_cast<int>(idle.size()));
  // And a bad timeout is refused.
  options.idle_timeout_s = 0;
  EXPECT_THROW(IgtlDeviceServer bad(options), Error);
}

// #44 item 6, limits per address: one host's idle connections recycle their own slots, never
// another host's (here the loopback net's 127.0.0.2 and 127.0.0.3), and a device still gets in.
TEST(IgtlDevice, OneHostsIdleConnectionsNeverTakeAnotherHostsSlots) {
  IgtlServerOptions options = AnyPort();
  options.max_connections = 7;  // room for the two hosts' 3 each and a device
  options.max_unproved_per_address = 3;
  options.idle_timeout_s = 30;  // the limits act here, not the timeout
  IgtlDeviceServer server(options);
  std::vector<std::unique_ptr<RawClient>> other, flood;
  for (int i = 0; i < 3; ++i) other.push_back(std::make_unique<RawClient>(server.port(), "127.0.0.3"));
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  for (int i = 0; i < 10; ++i) {
    flood.push_back(std::make_unique<RawClient>(server.port(), "127.0.0.2"));
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  for (std::size_t i = 0; i < other.size(); ++i)
    EXPECT_FALSE(other[i]->ClosedWithin(100)) << "the other host's connection " << i << " was put out";
  int flood_closed = 0;
  for (auto& c : flood) flood_closed += c->ClosedWithin(100);
  EXPECT_EQ(flood_closed, 7) << "the flooding host keeps 3 slots";
  // A device from a third address gets in, and keeps streaming while the flood goes on.
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  RawClient device(server.port());
  DeviceSample s;
  std::uint64_t seq = 0;
  std::chrono::steady_clock::time_point at;
  device.Send(Message("TRANSFORM", "left", TransformBody(X)));
  ASSERT_TRUE(Eventually([&] { return server.Latest("left", &s, &seq, &at); }));
  for (int i = 0; i < 6; ++i) flood.push_back(std::make_unique<RawClient>(server.port(), "127.0.0.2"));
  const std::uint64_t last = seq;
  device.Send(Message("TRANSFORM", "left", TransformBody(X)));
  ASSERT_TRUE(Eventually([&] { return server.Latest("left", &s, &seq, &at) && seq > last; }));
  for (std::size_t i = 0; i < other.size(); ++i) EXPECT_FALSE(other[i]->ClosedWithin(50)) << i;
  // A limit of zero is refused.
  options.max_unproved_per_address = 0;
  EXPECT_THROW(IgtlDeviceServer bad(options), Error);
}

TEST(IgtlDevice, APortInUseAndBadAddressesAreClearErrors) {
  IgtlDeviceServer first(AnyPort());
  IgtlServerOptions o;
  o.port = first.port();
  try {
    IgtlDeviceServer second(o);
    ADD_FAILURE() << "a second server bound the same port";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("already in use"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find(std::to_string(first.port())), std::string::npos) << e.what();
  }
  IgtlServerOptions p;
  EXPECT_THROW(ParseListenAddress("host:99999", &p), Error);
  EXPECT_THROW(ParseListenAddress("example.org:18944", &p), Error);
  EXPECT_THROW(ParseListenAddress("abc", &p), Error);
  ParseListenAddress("18945", &p);
  EXPECT_EQ(p.address, "127.0.0.1");  // localhost unless told otherwise
  EXPECT_EQ(p.port, 18945);
  ParseListenAddress("0.0.0.0:18946", &p);
  EXPECT_EQ(p.address, "0.0.0.0");
}

}  // namespace
}  // namespace trocar::control
