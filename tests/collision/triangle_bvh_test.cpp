// The exact segment/box–mesh queries under the collision checker (collision/triangle_bvh.hpp):
// the hierarchy answers as brute force over every triangle, the closed-form pieces agree with
// dense sampling, and the joint search finds the nearest of many queries.
#include "collision/triangle_bvh.hpp"

#include <random>

#include <gtest/gtest.h>

#include "test_util.hpp"

namespace trocar {
namespace {

using collision::MeshClosest;
using collision::MeshQuery;
using collision::TriangleBvh;
using Eigen::Vector3d;

// A closed, bumpy, irregular sphere-like surface (radius 0.1 ± 0.02 m) with 2·rings·segments
// triangles, vertices jittered: no symmetry for the hierarchy to exploit.
TriangleMesh Bumpy(std::mt19937& rng, int rings, int segments) {
  std::uniform_real_distribution<double> jitter(-0.3, 0.3);
  auto radius = [](double phi, double th) { return 0.1 + 0.02 * std::sin(3 * phi) * std::cos(5 * th); };
  return test::UvSphere(rings, segments, [&](int r, int s) {
    const bool pole = r == 0 || r == rings;
    const double phi = M_PI * (r + (pole ? 0.0 : jitter(rng))) / rings;
    const double th = 2 * M_PI * (s + (pole ? 0.0 : jitter(rng))) / segments;
    return Vector3d(radius(phi, th) * Vector3d(std::sin(phi) * std::cos(th), std::sin(phi) * std::sin(th), std::cos(phi)));
  });
}

Vector3d RandomPoint(std::mt19937& rng, double range) {
  std::uniform_real_distribution<double> u(-range, range);
  return Vector3d(u(rng), u(rng), u(rng));
}

Eigen::Isometry3d RandomPose(std::mt19937& rng, double range) {
  Eigen::Isometry3d X = Eigen::Isometry3d::Identity();
  std::normal_distribution<double> n(0, 1);
  X.linear() = Eigen::Quaterniond(n(rng), n(rng), n(rng), n(rng)).normalized().toRotationMatrix();
  X.translation() = RandomPoint(rng, range);
  return X;
}

TEST(TriangleBvh, SegmentBoxDistanceMatchesDenseSampling) {
  std::mt19937 rng(11);
  for (int trial = 0; trial < 1000; ++trial) {
    const Vector3d c = RandomPoint(rng, 0.1),
                   h = RandomPoint(rng, 0.05).cwiseAbs() + Vector3d::Constant(1e-3);
    const Vector3d a = RandomPoint(rng, 0.2), b = trial % 10 == 0 ? a : RandomPoint(rng, 0.2);
    double t = -1;
    const double d2 = collision::SegmentBoxDistanceSquared(a, b, c - h, c + h, &t);
    double sampled = std::numeric_limits<double>::infinity();
    for (int k = 0; k <= 4000; ++k) {
      const Vector3d p = a + (k / 4000.0) * (b - a);
      sampled = std::min(sampled, (p - p.cwiseMax(c - h).cwiseMin(c + h)).norm());
    }
    // Exact is never above any sample, and within the sampling step below the best one.
    EXPECT_LE(std::sqrt(d2), sampled + 1e-12) << "trial " << trial;
    EXPECT_GE(std::sqrt(d2), sampled - (b - a).norm() / 4000 - 1e-12) << "trial " << trial;
    if (d2 > 0) {
      ASSERT_GE(t, 0.0);
      ASSERT_LE(t, 1.0);
      const Vector3d p = a + t * (b - a);
      EXPECT_NEAR((p - p.cwiseMax(c - h).cwiseMin(c + h)).squaredNorm(), d2, 1e-15);
    }
  }
}

TEST(TriangleBvh, SegmentAndBoxTriangleDistancesAreNeverAboveSampledPairs) {
  // Closest points must be points of both shapes at the returned distance, and no sampled pair
  // of points may be nearer.
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> unit(0, 1);
  for (int trial = 0; trial < 300; ++trial) {
    const Vector3d v0 = RandomPoint(rng, 0.1), v1 = RandomPoint(rng, 0.1),
                   v2 = RandomPoint(rng, 0.1);
    const Vector3d a = RandomPoint(rng, 0.15), b = RandomPoint(rng, 0.15);
    const Vector3d half = RandomPoint(rng, 0.04).cwiseAbs() + Vector3d::Constant(2e-3);
    Vector3d ps, pt, pb, ptb;
    const double d = collision::SegmentTriangleClosest(a, b, v0, v1, v2, &ps, &pt);
    const double db = collision::BoxTriangleClosest(half, v0, v1, v2, &pb, &ptb);
    EXPECT_NEAR((ps - pt).norm(), d, 1e-12);
    EXPECT_NEAR((pb - ptb).norm(), db, 1e-12);
    // ps on the segment, pb in the box.
    EXPECT_NEAR(((ps - a).cross(b - a)).norm(), 0.0, 1e-12);
    EXPECT_TRUE((pb.cwiseAbs() - half).maxCoeff() < 1e-12);
    double sampled = std::numeric_limits<double>::infinity(), sampled_box = sampled;
    for (int k = 0; k < 3000; ++k) {
      double u = unit(rng), v = unit(rng);
      if (u + v > 1) u = 1 - u, v = 1 - v;
      const Vector3d q = v0 + u * (v1 - v0) + v * (v2 - v0);
      const Vector3d s = a + unit(rng) * (b - a);
      sampled = std::min(sampled, (q - s).norm());
      sampled_box = std::min(sampled_box, (q - q.cwiseMax(-half).cwiseMin(half)).norm());
    }
    EXPECT_LE(d, sampled + 1e-12) << "trial " << trial;
    EXPECT_LE(db, sampled_box + 1e-12) << "trial " << trial;
  }
}

TEST(TriangleBvh, AnswersAsBruteForceOverEveryTriangle) {
  std::mt19937 rng(13);
  const TriangleMesh mesh = Bumpy(rng, 30, 50);  // 2,900 triangles
  for (int leaf : {1, 4, 16}) {
    const TriangleBvh bvh(mesh, leaf);
    ASSERT_EQ(bvh.triangle_count(), static_cast<int>(mesh.triangles.size()));
    for (int trial = 0; trial < test::Trials(150, 40); ++trial) {
      // Segments and points inside, across and outside the surface; boxes turned every way.
      const Vector3d a = RandomPoint(rng, 0.2);
      const Vector3d b = trial % 7 == 0 ? a : a + RandomPoint(rng, 0.1);
      const MeshClosest fast = bvh.Closest(a, b), slow = bvh.ClosestBruteForce(a, b);
      ASSERT_TRUE(fast.found());
      // Equal up to rounding (triangles sharing the nearest edge or vertex give it both ways).
      EXPECT_NEAR(fast.distance, slow.distance, 1e-14) << "leaf " << leaf << " trial " << trial;
      EXPECT_NEAR((fast.p_M_query - fast.p_M_mesh).norm(), fast.distance, 1e-12);
      // With a bound: found exactly when nearer than it.
      const double bound = slow.distance * (trial % 2 ? 1.5 : 0.9);
      if (std::abs(bound - slow.distance) > 1e-12) {
        EXPECT_EQ(bvh.Closest(a, b, bound).found(), slow.distance < bound);
      }

      const Eigen::Isometry3d X_MB = RandomPose(rng, 0.2);
      const Vector3d half = RandomPoint(rng, 0.05).cwiseAbs() + Vector3d::Constant(2e-3);
      const MeshClosest box = bvh.ClosestToBox(X_MB, half),
                        box_slow = bvh.ClosestToBoxBruteForce(X_MB, half);
      ASSERT_TRUE(box.found());
      EXPECT_NEAR(box.distance, box_slow.distance, 1e-14) << "leaf " << leaf << " trial " << trial;
      EXPECT_NEAR((box.p_M_query - box.p_M_mesh).norm(), box.distance, 1e-12);
    }
  }
}

// The ray's first crossing (the cannula's track leaving the skin, port_rules.hpp) is the nearest
// crossing of every triangle, computed here without the hierarchy: rays from inside cross the
// closed surface exactly once within reach, rays from outside zero or more times.
TEST(TriangleBvh, FirstHitIsTheNearestCrossingOfAnyTriangle) {
  std::mt19937 rng(29);
  const TriangleMesh mesh = Bumpy(rng, 24, 40);
  const TriangleBvh bvh(mesh);
  // Any triangle's crossing by a ray, by the triangle's plane and the signs of three volumes.
  auto crossing = [&](const Vector3d& o, const Vector3d& d, int t) {
    const Vector3d a = mesh.vertices[mesh.triangles[t][0]], b = mesh.vertices[mesh.triangles[t][1]],
                   c = mesh.vertices[mesh.triangles[t][2]];
    const Vector3d n = (b - a).cross(c - a);
    const double den = n.dot(d);
    if (std::abs(den) < 1e-18) return std::numeric_limits<double>::infinity();
    const double h = n.dot(a - o) / den;
    if (h < 0) return std::numeric_limits<double>::infinity();
    const Vector3d p = o + h * d;
    const double s1 = n.dot((b - a).cross(p - a)), s2 = n.dot((c - b).cross(p - b)),
                 s3 = n.dot((a - c).cross(p - c));
    const bool inside = (s1 >= 0 && s2 >= 0 && s3 >= 0) || (s1 <= 0 && s2 <= 0 && s3 <= 0);
    return inside ? h : std::numeric_limits<double>::infinity();
  };
  int hits = 0, misses = 0;
  for (int trial = 0; trial < test::Trials(400, 80); ++trial) {
    const Vector3d o = RandomPoint(rng, trial % 2 ? 0.05 : 0.3);
    const Vector3d d = RandomPoint(rng, 1.0).normalized();
    double slow = std::numeric_limits<double>::infinity();
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t)
      slow = std::min(slow, crossing(o, d, static_cast<int>(t)));
    const double fast = bvh.FirstHit(o, 3.0 * d);  // any length of direction
    if (std::isfinite(slow)) {
      ++hits;
      EXPECT_NEAR(fast, slow, 1e-9) << "trial " << trial;
      // Within a limit short of the crossing: none.
      EXPECT_FALSE(std::isfinite(bvh.FirstHit(o, d, 0.99 * slow))) << "trial " << trial;
    } else {
      ++misses;
      EXPECT_FALSE(std::isfinite(fast)) << "trial " << trial;
    }
  }
  EXPECT_GT(hits, 10);
  EXPECT_GT(misses, 3);
}

TEST(TriangleBvh, TouchesCountsContactsOutsideTheExcludedBallOnly) {
  std::mt19937 rng(14);
  const TriangleMesh mesh = Bumpy(rng, 30, 50);
  const TriangleBvh bvh(mesh);
  int outside = 0, excluded_only = 0;
  for (int trial = 0; trial < 500; ++trial) {
    const Vector3d a = RandomPoint(rng, 0.15), b = a + RandomPoint(rng, 0.08);
    const double radius = 0.002 + 0.01 * (trial % 5);
    // The ball around where the axis is nearest the surface (a port) in most trials.
    const Vector3d centre = trial % 4 ? bvh.Closest(a, b).p_M_mesh : RandomPoint(rng, 0.12);
    const double exclude = trial % 3 == 0 ? -1.0 : 0.03;
    const auto hit = bvh.Touches(a, b, radius, centre, exclude);
    // Brute force: every triangle within the radius, by where its nearest point lies.
    bool any_outside = false, any_excluded = false;
    for (const auto& t : mesh.triangles) {
      Vector3d ps, pt;
      const double d = collision::SegmentTriangleClosest(
          a, b, mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]], &ps, &pt);
      if (d > radius) continue;
      if (exclude >= 0 && (pt - centre).norm() <= exclude) {
        any_excluded = true;
      } else {
        any_outside = true;
      }
    }
    EXPECT_EQ(hit.outside, any_outside) << "trial " << trial;
    if (!any_outside) {
      EXPECT_EQ(hit.excluded, any_excluded) << "trial " << trial;
    }
    if (hit.outside) {
      EXPECT_GE(hit.depth, 0.0);
      EXPECT_LE(hit.depth, radius);
      if (exclude >= 0) {
        EXPECT_GT((hit.p_M - centre).norm(), exclude);
      }
    }
    outside += any_outside;
    excluded_only += !any_outside && any_excluded;
  }
  EXPECT_GT(outside, 50);
  EXPECT_GT(excluded_only, 5);
}

TEST(TriangleBvh, JointSearchFindsTheNearestOfManyQueries) {
  std::mt19937 rng(15);
  const TriangleMesh m1 = Bumpy(rng, 30, 50), m2 = Bumpy(rng, 20, 30);
  const TriangleBvh b1(m1), b2(m2);
  TriangleBvh::Scratch scratch;
  for (int trial = 0; trial < test::Trials(80, 25); ++trial) {
    std::vector<MeshQuery> queries;
    double expected = std::numeric_limits<double>::infinity();
    int expected_query = -1;
    for (int q = 0; q < 12; ++q) {
      MeshQuery query;
      query.mesh = q % 2 ? &b1 : &b2;
      query.box = q % 3 == 0;
      query.a_M = RandomPoint(rng, 0.3);
      query.b_M = query.a_M + RandomPoint(rng, 0.1);
      query.radius = 0.01;
      query.X_MB = RandomPose(rng, 0.3);
      query.half = RandomPoint(rng, 0.03).cwiseAbs() + Vector3d::Constant(2e-3);
      const double d =
          query.box
              ? query.mesh->ClosestToBoxBruteForce(query.X_MB, query.half).distance
              : std::max(0.0, query.mesh->ClosestBruteForce(query.a_M, query.b_M).distance - 0.01);
      if (d < expected) {
        expected = d;
        expected_query = q;
      }
      queries.push_back(query);
    }
    const auto nearest =
        TriangleBvh::ClosestOfAll(queries, std::numeric_limits<double>::infinity(), &scratch);
    ASSERT_GE(nearest.query, 0);
    EXPECT_NEAR(nearest.distance, expected, 1e-12) << "trial " << trial;
    if (expected > 0) {
      EXPECT_EQ(nearest.query, expected_query);
      EXPECT_NEAR((nearest.p_M_query - nearest.p_M_mesh).norm(), nearest.distance, 1e-9);
    }
    EXPECT_LT(TriangleBvh::ClosestOfAll(queries, expected, &scratch).query,
              0);  // nothing nearer than itself
  }
}

}  // namespace
}  // namespace trocar
