// Segment (capsule axis) against triangle mesh: exact closest points over an AABB hierarchy.
// Closest-point routines after C. Ericson, Real-Time Collision Detection (2005), §5.1.5, §5.1.9.
#include "collision/triangle_bvh.hpp"

#include <algorithm>
#include <cmath>
#include <tuple>
#include <type_traits>
#include <utility>

#include "common/error.hpp"

namespace trocar::collision {
namespace {

using Eigen::Vector3d;

Vector3d ClosestPointTriangle(const Vector3d& p, const Vector3d& a, const Vector3d& b,
                              const Vector3d& c) {
  const Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + d1 / (d1 - d3) * ab;
  const Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + d2 / (d2 - d6) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  }
  const double denom = 1.0 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

}  // namespace

double SegmentSegmentClosest(const Vector3d& p1, const Vector3d& q1, const Vector3d& p2,
                             const Vector3d& q2, Vector3d* c1, Vector3d* c2) {
  const Vector3d d1 = q1 - p1, d2 = q2 - p2, r = p1 - p2;
  const double a = d1.squaredNorm(), e = d2.squaredNorm(), f = d2.dot(r);
  double s = 0.0, t = 0.0;
  if (a <= 0.0 && e <= 0.0) {
    s = t = 0.0;
  } else if (a <= 0.0) {
    t = std::clamp(f / e, 0.0, 1.0);
  } else {
    const double c = d1.dot(r);
    if (e <= 0.0) {
      s = std::clamp(-c / a, 0.0, 1.0);
    } else {
      const double b = d1.dot(d2);
      const double denom = a * e - b * b;
      s = denom > 1e-14 * a * e ? std::clamp((b * f - c * e) / denom, 0.0, 1.0) : 0.0;
      t = (b * s + f) / e;
      if (t < 0.0) {
        t = 0.0;
        s = std::clamp(-c / a, 0.0, 1.0);
      } else if (t > 1.0) {
        t = 1.0;
        s = std::clamp((b - c) / a, 0.0, 1.0);
      }
    }
  }
  *c1 = p1 + d1 * s;
  *c2 = p2 + d2 * t;
  return (*c1 - *c2).squaredNorm();
}

namespace {

// Where the segment crosses the triangle's interior (or boundary), if it does.
bool SegmentCrossesTriangle(const Vector3d& a, const Vector3d& b, const Vector3d& v0,
                            const Vector3d& v1, const Vector3d& v2, Vector3d* p) {
  const Vector3d e0 = v1 - v0, e1 = v2 - v0;
  const Vector3d n = e0.cross(e1);
  const double sa = n.dot(a - v0), sb = n.dot(b - v0);
  if ((sa > 0 && sb > 0) || (sa < 0 && sb < 0) || sa == sb)
    return false;  // one side, or in the plane
  const Vector3d x = a + sa / (sa - sb) * (b - a);
  const Vector3d w = x - v0;
  const double d00 = e0.dot(e0), d01 = e0.dot(e1), d11 = e1.dot(e1), d20 = w.dot(e0),
               d21 = w.dot(e1);
  const double den = d00 * d11 - d01 * d01;
  const double v = (d11 * d20 - d01 * d21) / den;
  const double u = (d00 * d21 - d01 * d20) / den;
  if (v < 0 || u < 0 || u + v > 1) return false;
  *p = x;
  return true;
}

}  // namespace

double SegmentTriangleClosest(const Vector3d& a, const Vector3d& b, const Vector3d& v0,
                              const Vector3d& v1, const Vector3d& v2, Vector3d* p_segment,
                              Vector3d* p_triangle) {
  Vector3d x;
  if (SegmentCrossesTriangle(a, b, v0, v1, v2, &x)) {
    *p_segment = *p_triangle = x;
    return 0.0;
  }
  // Not crossing: the closest pair has a segment end or a triangle edge in it.
  *p_segment = a;
  *p_triangle = ClosestPointTriangle(a, v0, v1, v2);
  double best = (*p_segment - *p_triangle).squaredNorm();
  if (a == b) return std::sqrt(best);
  auto consider = [&](const Vector3d& ps, const Vector3d& pt, double d2) {
    if (d2 < best) {
      best = d2;
      *p_segment = ps;
      *p_triangle = pt;
    }
  };
  const Vector3d qb = ClosestPointTriangle(b, v0, v1, v2);
  consider(b, qb, (b - qb).squaredNorm());
  Vector3d c1, c2;
  const Vector3d* edges[3][2] = {{&v0, &v1}, {&v1, &v2}, {&v2, &v0}};
  for (const auto& e : edges) {
    const double d2 = SegmentSegmentClosest(a, b, *e[0], *e[1], &c1, &c2);
    consider(c1, c2, d2);
  }
  return std::sqrt(best);
}

double SegmentBoxDistanceSquared(const Vector3d& a, const Vector3d& b, const Vector3d& lo,
                                 const Vector3d& hi, double* t_best) {
  const Vector3d d = b - a;
  // The squared distance along the segment is a convex piecewise quadratic in t, with pieces
  // between the parameters where the segment crosses a face plane.
  double ts[8];
  int n = 0;
  ts[n++] = 0.0;
  for (int i = 0; i < 3; ++i) {
    if (d[i] == 0.0) continue;
    for (double bound : {lo[i], hi[i]}) {
      const double t = (bound - a[i]) / d[i];
      if (t > 0.0 && t < 1.0) ts[n++] = t;
    }
  }
  ts[n++] = 1.0;
  for (int i = 2; i < n - 1; ++i) {  // insertion sort of the (at most 6) crossings
    for (int k = i; k > 1 && ts[k - 1] > ts[k]; --k) std::swap(ts[k - 1], ts[k]);
  }
  double best = std::numeric_limits<double>::infinity();
  for (int k = 0; k + 1 < n; ++k) {
    const double t0 = ts[k], t1 = ts[k + 1], tm = 0.5 * (t0 + t1);
    double A = 0, B = 0, C = 0;
    for (int i = 0; i < 3; ++i) {
      const double p = a[i] + tm * d[i];
      double c0;
      if (p < lo[i]) {
        c0 = a[i] - lo[i];
      } else if (p > hi[i]) {
        c0 = a[i] - hi[i];
      } else {
        continue;
      }
      A += d[i] * d[i];
      B += 2.0 * c0 * d[i];
      C += c0 * c0;
    }
    double t = B > 0 ? t0 : t1;
    if (A > 0) t = std::clamp(-B / (2 * A), t0, t1);
    const double value = (A * t + B) * t + C;
    if (value < best) {
      best = value;
      if (t_best) *t_best = t;
    }
    if (best <= 0.0) return 0.0;
  }
  return std::max(best, 0.0);
}

double BoxTriangleClosest(const Vector3d& half, const Vector3d& v0, const Vector3d& v1,
                          const Vector3d& v2, Vector3d* p_box, Vector3d* p_triangle) {
  // Two convex polytopes: when apart, the closest pair has a box edge or a triangle edge in it
  // (vertex-face, edge-edge); when they meet, a box edge crosses the triangle or a triangle edge
  // enters the box.
  double best2 = std::numeric_limits<double>::infinity();
  const Vector3d* tri[3] = {&v0, &v1, &v2};
  for (int e = 0; e < 3; ++e) {
    const Vector3d& a = *tri[e];
    const Vector3d& b = *tri[(e + 1) % 3];
    double t = 0.0;
    const double d2 = SegmentBoxDistanceSquared(a, b, -half, half, &t);
    if (d2 < best2) {
      best2 = d2;
      *p_triangle = a + t * (b - a);
      *p_box = p_triangle->cwiseMax(-half).cwiseMin(half);
      if (d2 <= 0.0) return 0.0;
    }
  }
  Vector3d ps, pt;
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, w = (axis + 2) % 3;
    for (int corner = 0; corner < 4; ++corner) {
      Vector3d a;
      a[u] = (corner & 1) ? half[u] : -half[u];
      a[w] = (corner & 2) ? half[w] : -half[w];
      a[axis] = -half[axis];
      Vector3d b = a;
      b[axis] = half[axis];
      const double d = SegmentTriangleClosest(a, b, v0, v1, v2, &ps, &pt);
      if (d * d < best2) {
        best2 = d * d;
        *p_box = ps;
        *p_triangle = pt;
        if (d <= 0.0) return 0.0;
      }
    }
  }
  return std::sqrt(best2);
}

TriangleBvh::TriangleBvh(const TriangleMesh& mesh, int leaf_size) {
  TROCAR_THROW_UNLESS(leaf_size >= 1, "triangle BVH: leaf size " << leaf_size << ", expected >= 1");
  triangles_.reserve(mesh.triangles.size());
  for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
    const auto& t = mesh.triangles[i];
    triangles_.push_back(
        {mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]], static_cast<int>(i)});
  }
  nodes_.reserve(2 * triangles_.size() / leaf_size + 2);
  nodes_.emplace_back();
  if (!triangles_.empty()) Build(0, static_cast<int>(triangles_.size()), leaf_size);
}

void TriangleBvh::Build(int begin, int end, int leaf_size) {
  // Iterative over an explicit stack: node index, triangle range.
  struct Job {
    int node, begin, end;
  };
  std::vector<Job> jobs{{0, begin, end}};
  while (!jobs.empty()) {
    const Job job = jobs.back();
    jobs.pop_back();
    Vector3d lo = Vector3d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
    Vector3d clo = lo, chi = hi;
    for (int i = job.begin; i < job.end; ++i) {
      const Triangle& t = triangles_[i];
      lo = lo.cwiseMin(t.v0).cwiseMin(t.v1).cwiseMin(t.v2);
      hi = hi.cwiseMax(t.v0).cwiseMax(t.v1).cwiseMax(t.v2);
      const Vector3d c = (t.v0 + t.v1 + t.v2) / 3.0;
      clo = clo.cwiseMin(c);
      chi = chi.cwiseMax(c);
    }
    nodes_[job.node].lo = lo;
    nodes_[job.node].hi = hi;
    if (job.end - job.begin <= leaf_size) {
      nodes_[job.node].first = job.begin;
      nodes_[job.node].count = job.end - job.begin;
      continue;
    }
    int axis = 0;
    (chi - clo).maxCoeff(&axis);
    const int mid = (job.begin + job.end) / 2;
    std::nth_element(triangles_.begin() + job.begin, triangles_.begin() + mid,
                     triangles_.begin() + job.end, [axis](const Triangle& x, const Triangle& y) {
                       return x.v0[axis] + x.v1[axis] + x.v2[axis] <
                              y.v0[axis] + y.v1[axis] + y.v2[axis];
                     });
    const int left = static_cast<int>(nodes_.size());
    nodes_.emplace_back();
    nodes_.emplace_back();
    nodes_[job.node].first = left;
    nodes_[job.node].count = 0;
    jobs.push_back({left, job.begin, mid});
    jobs.push_back({left + 1, mid, job.end});
  }
}

namespace {

// Queries for TriangleBvh::Search: NodeBound2 (a lower bound on the squared distance to a box of
// the hierarchy) and Leaf (exact closest points to one triangle).
// Squared gap between two axis-aligned boxes: a lower bound of the squared distance between
// anything inside them, a few comparisons where an exact bound costs a piecewise minimisation.
inline double AabbGap2(const Vector3d& lo1, const Vector3d& hi1, const Vector3d& lo2,
                       const Vector3d& hi2) {
  return (lo1 - hi2).cwiseMax(lo2 - hi1).cwiseMax(0.0).squaredNorm();
}

// Whether the ray origin + t d, t in [0, limit], meets the closed box [lo, hi], given d's
// componentwise inverse (slabs: the parameters inside each axis's pair of planes overlap). Along
// a direction parallel to a slab the inverse is infinite: the ray is inside that slab or never.
inline bool RayMeetsBox(const Vector3d& origin, const Vector3d& inv_d, const Vector3d& lo,
                        const Vector3d& hi, double limit) {
  double t0 = 0.0, t1 = limit;
  for (int k = 0; k < 3; ++k) {
    double a = (lo[k] - origin[k]) * inv_d[k], b = (hi[k] - origin[k]) * inv_d[k];
    if (std::isnan(a) || std::isnan(b)) {  // parallel to the slab, on its boundary
      if (origin[k] < lo[k] || origin[k] > hi[k]) return false;
      continue;
    }
    if (a > b) std::swap(a, b);
    t0 = std::max(t0, a);
    t1 = std::min(t1, b);
    if (t0 > t1) return false;
  }
  return true;
}

struct SegmentQuery {
  Vector3d a, b;
  Vector3d lo, hi;  // the segment's bounds
  Vector3d inv_ab;  // (b - a)'s componentwise inverse, for RayMeetsBox
  SegmentQuery(const Vector3d& a_in, const Vector3d& b_in)
      : a(a_in), b(b_in), lo(a_in.cwiseMin(b_in)), hi(a_in.cwiseMax(b_in)),
        inv_ab((b_in - a_in).cwiseInverse()) {}
  // A cheaper lower bound of NodeBound2 (a node it puts beyond a radius is beyond it exactly).
  double CheapBound2(const Vector3d& node_lo, const Vector3d& node_hi) const {
    return AabbGap2(lo, hi, node_lo, node_hi);
  }
  double NodeBound2(const Vector3d& lo_n, const Vector3d& hi_n) const {
    return SegmentBoxDistanceSquared(a, b, lo_n, hi_n);
  }
  // Whether NodeBound2(lo_n, hi_n) > r2, as TouchesWith asks it of every node: the exact distance
  // only where three slab tests leave it open. A segment that crosses the box is at distance 0; one
  // that misses the box grown by r on every side is farther than r from it (every point within r
  // of the box lies inside the grown box). A shaft through its port crosses every node on its way
  // to the leaves; a piecewise minimisation per node cost a fifth of a plan's verification.
  // Between the two, one that crosses the box grown by r / √3 (less a rounding) is within r of
  // it (a point of that box is at most √3 of the growth from the box).
  bool Beyond(const Vector3d& lo_n, const Vector3d& hi_n, double r, double r2) const {
    if (RayMeetsBox(a, inv_ab, lo_n, hi_n, 1.0)) return false;
    const Vector3d grown = Vector3d::Constant(r * (1.0 + 1e-9) + 1e-12);  // rounding: more
    if (!RayMeetsBox(a, inv_ab, lo_n - grown, hi_n + grown, 1.0)) return true;
    const Vector3d within = Vector3d::Constant(r * (1.0 / std::sqrt(3.0)) * (1.0 - 1e-9));  // less
    if (RayMeetsBox(a, inv_ab, lo_n - within, hi_n + within, 1.0)) return false;
    return NodeBound2(lo_n, hi_n) > r2;
  }
  double Leaf(const Vector3d& v0, const Vector3d& v1, const Vector3d& v2, Vector3d* pq,
              Vector3d* pt, double /*best*/) const {
    return SegmentTriangleClosest(a, b, v0, v1, v2, pq, pt);
  }
};

struct BoxQuery {
  Eigen::Isometry3d X_MB, X_BM;
  Vector3d half;
  // The box inside a capsule around its longest axis: the node bound.
  Vector3d axis_a, axis_b;
  double axis_radius = 0.0;

  BoxQuery(const Eigen::Isometry3d& pose, const Vector3d& h)
      : X_MB(pose), X_BM(pose.inverse()), half(h) {
    int k = 0;
    half.maxCoeff(&k);
    Vector3d along = Vector3d::Zero();
    along[k] = half[k];
    axis_a = X_MB * (-along);
    axis_b = X_MB * along;
    Vector3d across = half;
    across[k] = 0.0;
    axis_radius = across.norm();
    const Vector3d reach_M = pose.linear().cwiseAbs() * half;
    lo = pose.translation() - reach_M;
    hi = pose.translation() + reach_M;
  }
  Vector3d lo, hi;  // the box's bounds in M
  double CheapBound2(const Vector3d& node_lo, const Vector3d& node_hi) const {
    return AabbGap2(lo, hi, node_lo, node_hi);
  }
  // Lower bounds, the largest of: the node's box against the box's axis-aligned bounds in M; the
  // node's box's bounds in B against the box; the enclosing capsule against the node's box.
  double NodeBound2(const Vector3d& lo, const Vector3d& hi) const {
    const Eigen::Matrix3d& R = X_MB.linear();
    const Vector3d c_M = 0.5 * (lo + hi), h_M = 0.5 * (hi - lo);
    const Vector3d reach_M = R.cwiseAbs() * half;  // the box's half extents along M's axes
    const double gap_M =
        ((c_M - X_MB.translation()).cwiseAbs() - h_M - reach_M).cwiseMax(0.0).squaredNorm();
    const Vector3d c_B = X_BM * c_M;
    const Vector3d reach_B =
        R.transpose().cwiseAbs() * h_M;  // the node's half extents along B's axes
    const double gap_B = (c_B.cwiseAbs() - half - reach_B).cwiseMax(0.0).squaredNorm();
    double bound2 = std::max(gap_M, gap_B);
    const double d = std::sqrt(SegmentBoxDistanceSquared(axis_a, axis_b, lo, hi)) - axis_radius;
    if (d > 0.0) bound2 = std::max(bound2, d * d);
    return bound2;
  }
  double Leaf(const Vector3d& v0, const Vector3d& v1, const Vector3d& v2, Vector3d* pq,
              Vector3d* pt, double best) const {
    const Vector3d u0 = X_BM * v0, u1 = X_BM * v1, u2 = X_BM * v2;
    // The triangle's bounds in B against the box first.
    const Vector3d lo = u0.cwiseMin(u1).cwiseMin(u2), hi = u0.cwiseMax(u1).cwiseMax(u2);
    if ((lo - half).cwiseMax(-half - hi).cwiseMax(0.0).squaredNorm() >= best * best) {
      return std::numeric_limits<double>::infinity();
    }
    const double d = BoxTriangleClosest(half, u0, u1, u2, pq, pt);
    *pq = X_MB * *pq;
    *pt = X_MB * *pt;
    return d;
  }
};

}  // namespace

template <typename Query>
MeshClosest TriangleBvh::Search(const Query& query, double bound) const {
  MeshClosest out;
  if (triangles_.empty()) return out;
  double best = bound, best2 = bound * bound;
  struct Entry {
    int node;
    double lb2;
  };
  Entry stack[128];
  int top = 0;
  const double root = query.NodeBound2(nodes_[0].lo, nodes_[0].hi);
  if (root >= best2) return out;
  stack[top++] = {0, root};
  Vector3d pq, pt;
  while (top > 0) {
    const Entry e = stack[--top];
    if (e.lb2 >= best2) continue;
    const Node& node = nodes_[e.node];
    if (node.count > 0) {
      for (int i = node.first; i < node.first + node.count; ++i) {
        const Triangle& t = triangles_[i];
        const double d = query.Leaf(t.v0, t.v1, t.v2, &pq, &pt, best);
        if (d < best) {
          best = d;
          best2 = d * d;
          out.distance = d;
          out.p_M_query = pq;
          out.p_M_mesh = pt;
          out.triangle = t.index;
          if (d <= 0.0) return out;
        }
      }
      continue;
    }
    const Node& l = nodes_[node.first];
    const Node& r = nodes_[node.first + 1];
    // The cheap bound first: a child it already puts beyond the best is never pushed.
    auto bound2 = [&](const Node& c) {
      const double cheap = query.CheapBound2(c.lo, c.hi);
      return cheap >= best2 ? cheap : query.NodeBound2(c.lo, c.hi);
    };
    const double dl = bound2(l);
    const double dr = bound2(r);
    // Nearer child on top of the stack.
    const bool left_first = dl <= dr;
    const Entry near{left_first ? node.first : node.first + 1, left_first ? dl : dr};
    const Entry far{left_first ? node.first + 1 : node.first, left_first ? dr : dl};
    if (far.lb2 < best2) stack[top++] = far;
    if (near.lb2 < best2) stack[top++] = near;
  }
  return out;
}

MeshClosest TriangleBvh::Closest(const Vector3d& a_M, const Vector3d& b_M, double bound) const {
  return Search(SegmentQuery{a_M, b_M}, bound);
}

MeshClosest TriangleBvh::ClosestToBox(const Eigen::Isometry3d& X_MB, const Vector3d& half,
                                      double bound) const {
  return Search(BoxQuery(X_MB, half), bound);
}

NearestQuery TriangleBvh::ClosestOfAll(const std::vector<MeshQuery>& queries, double bound,
                                       Scratch* scratch) {
  NearestQuery out;
  std::vector<BoxQuery> boxes;
  std::vector<int> box_of(queries.size(), -1);
  for (std::size_t q = 0; q < queries.size(); ++q) {
    if (queries[q].box) {
      box_of[q] = static_cast<int>(boxes.size());
      boxes.emplace_back(queries[q].X_MB, queries[q].half);
    }
  }
  double best = bound;
  // Lower bound on the surface distance from query q to node n (the boxes' gap first: a node it
  // already puts beyond the best is never pushed, so its exact bound is not needed).
  auto node_bound = [&](int q, int n) {
    const MeshQuery& query = queries[q];
    const Node& node = query.mesh->nodes_[n];
    if (query.box) {
      const BoxQuery& box = boxes[box_of[q]];
      const double cheap = std::sqrt(box.CheapBound2(node.lo, node.hi));
      return cheap >= best ? cheap : std::sqrt(box.NodeBound2(node.lo, node.hi));
    }
    const double cheap =
        std::sqrt(AabbGap2(query.a_M.cwiseMin(query.b_M), query.a_M.cwiseMax(query.b_M),
                           node.lo, node.hi)) -
        query.radius;
    if (cheap >= best) return cheap;
    return std::sqrt(SegmentBoxDistanceSquared(query.a_M, query.b_M, node.lo, node.hi)) -
           query.radius;
  };
  auto& heap = scratch->heap;
  heap.clear();
  auto later = [](const Scratch::Entry& x, const Scratch::Entry& y) {
    return std::tie(x.bound, x.query, x.node) > std::tie(y.bound, y.query, y.node);
  };
  for (std::size_t q = 0; q < queries.size(); ++q) {
    if (!queries[q].mesh || queries[q].mesh->triangles_.empty()) continue;
    const double b = node_bound(static_cast<int>(q), 0);
    if (b < best) heap.push_back({b, static_cast<int>(q), 0});
  }
  std::make_heap(heap.begin(), heap.end(), later);
  Vector3d pq, pt;
  while (!heap.empty()) {
    std::pop_heap(heap.begin(), heap.end(), later);
    const Scratch::Entry e = heap.back();
    heap.pop_back();
    if (e.bound >= best) break;  // the smallest bound left: nothing nearer remains
    const MeshQuery& query = queries[e.query];
    const TriangleBvh& mesh = *query.mesh;
    const Node& node = mesh.nodes_[e.node];
    if (node.count == 0) {
      for (int child : {node.first, node.first + 1}) {
        const double b = node_bound(e.query, child);
        if (b < best) {
          heap.push_back({b, e.query, child});
          std::push_heap(heap.begin(), heap.end(), later);
        }
      }
      continue;
    }
    for (int i = node.first; i < node.first + node.count; ++i) {
      const Triangle& t = mesh.triangles_[i];
      double d;
      if (query.box) {
        d = boxes[box_of[e.query]].Leaf(t.v0, t.v1, t.v2, &pq, &pt, best);
      } else {
        const double axis =
            SegmentTriangleClosest(query.a_M, query.b_M, t.v0, t.v1, t.v2, &pq, &pt);
        d = std::max(0.0, axis - query.radius);
        if (axis > query.radius)
          pq += query.radius / axis * (pt - pq);  // onto the capsule's surface
        else
          pq = pt;
      }
      if (d < best) {
        best = d;
        out.query = e.query;
        out.distance = d;
        out.p_M_query = pq;
        out.p_M_mesh = pt;
        if (d <= 0.0) return out;
      }
    }
  }
  return out;
}

namespace {
template <typename Query, typename Triangles>
MeshClosest BruteForce(const Query& query, const Triangles& triangles) {
  MeshClosest out;
  Vector3d pq, pt;
  for (const auto& t : triangles) {
    const double d =
        query.Leaf(t.v0, t.v1, t.v2, &pq, &pt, std::numeric_limits<double>::infinity());
    if (d < out.distance || (d == out.distance && t.index < out.triangle)) {
      out.distance = d;
      out.p_M_query = pq;
      out.p_M_mesh = pt;
      out.triangle = t.index;
    }
  }
  return out;
}
}  // namespace

MeshClosest TriangleBvh::ClosestBruteForce(const Vector3d& a_M, const Vector3d& b_M) const {
  return BruteForce(SegmentQuery{a_M, b_M}, triangles_);
}

MeshClosest TriangleBvh::ClosestToBoxBruteForce(const Eigen::Isometry3d& X_MB,
                                                const Vector3d& half) const {
  return BruteForce(BoxQuery(X_MB, half), triangles_);
}

template <typename Query>
SweptSphereContact TriangleBvh::TouchesWith(const Query& query, double radius,
                                            const Vector3d& exclude_centre,
                                            double exclude_radius) const {
  SweptSphereContact out;
  if (triangles_.empty()) return out;
  const double r2 = radius * radius;
  int stack[128];
  int top = 0;
  auto beyond = [&](const Node& n) {
    if (query.CheapBound2(n.lo, n.hi) > r2) return true;
    if constexpr (std::is_same_v<Query, SegmentQuery>) {
      return query.Beyond(n.lo, n.hi, radius, r2);
    } else {
      return query.NodeBound2(n.lo, n.hi) > r2;
    }
  };
  if (beyond(nodes_[0])) return out;
  stack[top++] = 0;
  Vector3d pq, pt;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    if (node.count > 0) {
      for (int i = node.first; i < node.first + node.count; ++i) {
        const Triangle& t = triangles_[i];
        const double d = query.Leaf(t.v0, t.v1, t.v2, &pq, &pt, radius + 1e-12);
        if (d > radius) continue;
        if (exclude_radius >= 0.0 && (pt - exclude_centre).norm() <= exclude_radius) {
          out.excluded = true;
          continue;
        }
        out.outside = true;
        out.p_M = pt;
        out.depth = radius - d;
        return out;
      }
      continue;
    }
    for (int c : {node.first, node.first + 1}) {
      if (!beyond(nodes_[c])) stack[top++] = c;
    }
  }
  return out;
}

SweptSphereContact TriangleBvh::Touches(const Vector3d& a_M, const Vector3d& b_M, double radius,
                                        const Vector3d& exclude_centre,
                                        double exclude_radius) const {
  return TouchesWith(SegmentQuery{a_M, b_M}, radius, exclude_centre, exclude_radius);
}

SweptSphereContact TriangleBvh::BoxTouches(const Eigen::Isometry3d& X_MB, const Vector3d& half,
                                           const Vector3d& exclude_centre,
                                           double exclude_radius) const {
  return TouchesWith(BoxQuery(X_MB, half), 0.0, exclude_centre, exclude_radius);
}

double TriangleBvh::FirstHit(const Vector3d& origin_M, const Vector3d& dir_M, double max_t) const {
  double best = std::numeric_limits<double>::infinity();
  if (triangles_.empty() || !(max_t > 0.0)) return best;
  const double n = dir_M.norm();
  if (!(n > 0.0)) return best;
  const Vector3d d = dir_M / n;
  const Vector3d inv(1.0 / d.x(), 1.0 / d.y(), 1.0 / d.z());
  auto enters = [&](const Node& node, double limit) {
    return RayMeetsBox(origin_M, inv, node.lo, node.hi, limit);
  };
  int stack[128];
  int top = 0;
  if (!enters(nodes_[0], max_t)) return best;
  stack[top++] = 0;
  while (top > 0) {
    const Node& node = nodes_[stack[--top]];
    if (!enters(node, std::min(best, max_t))) continue;
    if (node.count > 0) {
      for (int i = node.first; i < node.first + node.count; ++i) {
        // Moller-Trumbore, both faces.
        const Triangle& t = triangles_[i];
        const Vector3d e1 = t.v1 - t.v0, e2 = t.v2 - t.v0;
        const Vector3d p = d.cross(e2);
        const double det = e1.dot(p);
        if (std::abs(det) < 1e-15) continue;
        const Vector3d s = origin_M - t.v0;
        const double u = s.dot(p) / det;
        if (u < 0.0 || u > 1.0) continue;
        const Vector3d q = s.cross(e1);
        const double v = d.dot(q) / det;
        if (v < 0.0 || u + v > 1.0) continue;
        const double hit = e2.dot(q) / det;
        if (hit >= 0.0 && hit <= max_t && hit < best) best = hit;
      }
      continue;
    }
    for (int c : {node.first, node.first + 1}) stack[top++] = c;
  }
  return best;
}

}  // namespace trocar::collision
