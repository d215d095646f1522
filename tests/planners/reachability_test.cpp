// Which arm reaches which stretch of each target (issue #43 item 5), against a reference built
// sample by sample from seeded random plan files.
#include "plan/reachability.hpp"

#include <gtest/gtest.h>

#include <algorithm>
#include <map>
#include <numeric>
#include <random>
#include <set>

#include "common/error.hpp"

namespace trocar::planners {
namespace {

struct RandomPlan {
  PlanFile file;
  // Per arm and sample: the status the plan's data gives (the verified motion for an instrument
  // of a verified plan, else its reach; an endoscope's view), and the reason written when not.
  std::vector<std::vector<bool>> ok;
  std::vector<std::vector<std::string>> why;
};

RandomPlan MakeRandomPlan(unsigned seed) {
  std::mt19937 rng(seed);
  auto coin = [&](double p) { return std::uniform_real_distribution<double>(0, 1)(rng) < p; };
  RandomPlan r;
  PlanFile& f = r.file;
  f.path = "random.json";
  const bool scope = coin(0.7);
  auto arm = [&](const char* name, const char* role) {
    StoredArm a;
    a.name = name;
    a.role = role;
    f.arms.push_back(a);
  };
  arm("psm1", "instrument");
  arm("psm2", "instrument");
  if (scope) arm("ecm", "endoscope");
  const std::size_t na = f.arms.size();
  // Two targets, their samples interleaved in the file and out of order along each target.
  const int n_lad = 2 + static_cast<int>(rng() % 10), n_lima = 1 + static_cast<int>(rng() % 8);
  std::vector<std::pair<std::string, double>> samples;
  for (int i = 0; i < n_lad; ++i) samples.push_back({"LAD", 0.01 * i + 0.002});
  for (int i = 0; i < n_lima; ++i) samples.push_back({"LIMA", 0.015 * i});
  std::shuffle(samples.begin(), samples.end(), rng);
  for (std::size_t s = 0; s < samples.size(); ++s) {
    StoredSample sample;
    sample.index = static_cast<int>(s);
    sample.target = samples[s].first;
    sample.arc_length = samples[s].second;
    sample.p_W = Eigen::Vector3d(0.1 * s, 0, 1);
    f.samples.push_back(sample);
  }
  const std::size_t ns = f.samples.size();
  StoredPlan plan;
  plan.rank = 1;
  plan.verified = coin(0.6);
  r.ok.assign(na, std::vector<bool>(ns));
  r.why.assign(na, std::vector<std::string>(ns));
  const char* reasons[] = {"in collision: psm's shaft against the heart", "joint limit",
                           "unreachable"};
  // Statuses in runs along each target (each sample keeps its predecessor's with 70 %).
  for (std::size_t a = 0; a < na; ++a) {
    std::map<std::string, bool> last;
    std::vector<int> order(ns);
    std::iota(order.begin(), order.end(), 0);
    std::sort(order.begin(), order.end(),
              [&](int x, int y) { return f.samples[x].arc_length < f.samples[y].arc_length; });
    for (int s : order) {
      const std::string& t = f.samples[s].target;
      const bool v = last.count(t) && coin(0.7) ? last[t] : coin(0.6);
      last[t] = v;
      r.ok[a][s] = v;
      r.why[a][s] = v ? "" : reasons[rng() % 3];
    }
  }
  for (std::size_t a = 0; a < na; ++a) {
    const bool endoscope = f.arms[a].role == "endoscope";
    for (std::size_t s = 0; s < ns; ++s) {
      StoredReach reach;
      reach.sample = static_cast<int>(s);
      reach.arm = f.arms[a].name;
      reach.endoscope = endoscope;
      // A verified plan's instrument claims differ from its motions: the motions must win.
      const bool claim = plan.verified && !endoscope ? !r.ok[a][s] : r.ok[a][s];
      (endoscope ? reach.seen : reach.reached) = claim;
      reach.reached = endoscope ? true : reach.reached;
      reach.reason =
          claim ? "" : (plan.verified && !endoscope ? "the claim's reason" : r.why[a][s]);
      plan.reaches.push_back(reach);
      if (plan.verified && !endoscope) {
        StoredMotion m;
        m.arm = f.arms[a].name;
        m.sample = static_cast<int>(s);
        m.solved = r.ok[a][s];
        m.outcome = m.solved ? "solved" : "failed";
        m.reason = r.why[a][s];
        plan.motions.push_back(m);
        if (!m.solved) r.why[a][s] = "failed: " + m.reason;  // as the reachability says it
      }
    }
  }
  std::vector<bool> served(ns);
  for (std::size_t s = 0; s < ns; ++s) {
    bool all = true, seen = !scope;
    for (std::size_t a = 0; a < na; ++a) {
      if (f.arms[a].role == "endoscope")
        seen = seen || r.ok[a][s];
      else
        all = all && r.ok[a][s];
    }
    served[s] = all && seen;
  }
  (plan.verified ? plan.verified_served : plan.served) = served;
  f.plans.push_back(plan);
  return r;
}

TEST(TargetReachability, StretchesCutEachTargetWhereAnArmsStatusChanges) {
  int stretches = 0, partly = 0, served = 0, none = 0;
  for (unsigned seed = 1; seed <= 300; ++seed) {
    SCOPED_TRACE(seed);
    const RandomPlan rp = MakeRandomPlan(seed);
    const PlanFile& f = rp.file;
    const std::size_t na = f.arms.size();
    const Reachability r = TargetReachability(f, 0, [](const std::vector<Eigen::Vector3d>& p) {
      return std::to_string(p.size()) + " points";
    });
    EXPECT_EQ(r.verified, f.plans[0].verified);
    ASSERT_EQ(r.per_sample.size(), f.samples.size());
    // Each sample's class from the reference statuses.
    for (std::size_t s = 0; s < f.samples.size(); ++s) {
      bool some = false, all = true, seen = na == 2;
      for (std::size_t a = 0; a < na; ++a) {
        if (f.arms[a].role == "endoscope")
          seen = seen || rp.ok[a][s];
        else
          some = some || rp.ok[a][s];
        if (f.arms[a].role != "endoscope") all = all && rp.ok[a][s];
      }
      const ReachClass want =
          all && seen ? ReachClass::kServed : (some ? ReachClass::kPartly : ReachClass::kNone);
      EXPECT_EQ(r.per_sample[s], want) << s;
      served += want == ReachClass::kServed, partly += want == ReachClass::kPartly;
      none += want == ReachClass::kNone;
    }
    // Per target, the stretches partition its samples in their order along it.
    for (const std::string target : {"LAD", "LIMA"}) {
      std::vector<int> along;
      for (std::size_t s = 0; s < f.samples.size(); ++s)
        if (f.samples[s].target == target) along.push_back(static_cast<int>(s));
      std::sort(along.begin(), along.end(),
                [&](int x, int y) { return f.samples[x].arc_length < f.samples[y].arc_length; });
      std::vector<int> joined;
      const TargetStretch* previous = nullptr;
      for (const TargetStretch& st : r.stretches) {
        if (st.target != target) continue;
        ++stretches;
        joined.insert(joined.end(), st.samples.begin(), st.samples.end());
        EXPECT_EQ(st.from_m, f.samples[st.samples.front()].arc_length);
        EXPECT_EQ(st.to_m, f.samples[st.samples.back()].arc_length);
        EXPECT_EQ(st.level, std::to_string(st.samples.size()) + " points");
        ASSERT_EQ(st.arms.size(), na);
        for (std::size_t a = 0; a < na; ++a) {
          EXPECT_EQ(st.arms[a].arm, f.arms[a].name);
          std::set<std::string> whys;
          for (int s : st.samples) {
            EXPECT_EQ(st.arms[a].reaches, rp.ok[a][s]) << target << " sample " << s << " arm " << a;
            whys.insert(rp.why[a][s]);
          }
          if (!st.arms[a].reaches) {
            EXPECT_TRUE(whys.count(st.arms[a].why_not)) << st.arms[a].why_not;
          } else {
            EXPECT_EQ(st.arms[a].why_not, "");
          }
        }
        for (int s : st.samples) EXPECT_EQ(r.per_sample[s], st.reach);
        EXPECT_EQ(st.served, st.reach == ReachClass::kServed);
        if (previous) {
          bool differs = previous->reach != st.reach;
          for (std::size_t a = 0; a < na; ++a)
            differs = differs || previous->arms[a].reaches != st.arms[a].reaches;
          EXPECT_TRUE(differs) << "two neighbouring stretches of " << target << " alike";
        }
        previous = &st;
      }
      EXPECT_EQ(joined, along) << target;
    }
  }
  // The cases were varied: long and short stretches, every class.
  EXPECT_GT(stretches, 1200);
  EXPECT_GT(served, 200);
  EXPECT_GT(partly, 200);
  EXPECT_GT(none, 200);
}

TEST(TargetReachability, AMotionOfAnotherArmOrSampleIsRefusedNamingIt) {
  RandomPlan rp = MakeRandomPlan(3);
  PlanFile f = rp.file;
  StoredReach bad;
  bad.arm = "psm9";
  f.plans[0].reaches.push_back(bad);
  try {
    TargetReachability(f, 0);
    ADD_FAILURE() << "an unknown arm accepted";
  } catch (const Error& e) {
    EXPECT_NE(std::string(e.what()).find("'psm9'"), std::string::npos) << e.what();
  }
  f = rp.file;
  bad.arm = "psm1";
  bad.sample = static_cast<int>(f.samples.size());
  f.plans[0].reaches.push_back(bad);
  EXPECT_THROW(TargetReachability(f, 0), Error);
  EXPECT_THROW(TargetReachability(rp.file, 1), Error);
}

}  // namespace
}  // namespace trocar::planners

namespace trocar {
namespace {

// Where a stretch lies along its target, in a surgeon's words: the distance from the first point
// and the thirds it covers, each a third of the sampled length.
TEST(TargetReachability, AStretchIsSaidByItsDistanceAndTheThirdsOfTheVesselItCovers) {
  EXPECT_EQ(planners::AlongTarget(0.0, 0.057, 0.129),
            "0–57 mm from its first point (its proximal and middle thirds)");
  EXPECT_EQ(planners::AlongTarget(0.129, 0.129, 0.129),
            "129 mm from its first point (its distal third)");
  EXPECT_EQ(planners::AlongTarget(0.0, 0.129, 0.129),
            "0–129 mm from its first point (its whole length)");
  EXPECT_EQ(planners::AlongTarget(0.045, 0.080, 0.150),
            "45–80 mm from its first point (its proximal and middle thirds)");
  EXPECT_EQ(planners::AlongTarget(0.055, 0.095, 0.150),
            "55–95 mm from its first point (its middle third)");
  EXPECT_EQ(planners::AlongTarget(0.0, 0.0, 0.0), "0 mm from its first point");
  std::mt19937 rng(5);
  for (int i = 0; i < 500; ++i) {
    const double length = std::uniform_real_distribution<double>(0.02, 0.3)(rng);
    double a = std::uniform_real_distribution<double>(0.0, length)(rng);
    double b = std::uniform_real_distribution<double>(0.0, length)(rng);
    if (a > b) std::swap(a, b);
    const std::string text = planners::AlongTarget(a, b, length);
    const bool proximal = a < length / 3, distal = b >= 2 * length / 3;
    EXPECT_EQ(text.find("proximal") != std::string::npos || text.find("whole") != std::string::npos,
              proximal)
        << text;
    EXPECT_EQ(text.find("distal") != std::string::npos || text.find("whole") != std::string::npos,
              distal)
        << text;
    if (!proximal && !distal) EXPECT_NE(text.find("middle third"), std::string::npos) << text;
  }
}

}  // namespace
}  // namespace trocar
