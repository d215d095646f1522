#include "common/mesh.hpp"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <unordered_map>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar {

double TriangleArea(const TriangleMesh& mesh, const Eigen::Vector3i& t) {
  const Eigen::Vector3d& a = mesh.vertices[t[0]];
  return 0.5 * (mesh.vertices[t[1]] - a).cross(mesh.vertices[t[2]] - a).norm();
}

Eigen::Vector3d ClosestPointOnTriangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a,
                                       const Eigen::Vector3d& b, const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + d1 / (d1 - d3) * ab;
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + d2 / (d2 - d6) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  const double denom = va + vb + vc;
  if (!(std::abs(denom) > 0)) return a;  // degenerate triangle
  return a + ab * (vb / denom) + ac * (vc / denom);
}

double DistanceToMesh(const TriangleMesh& mesh, const Eigen::Vector3d& p) {
  double best = std::numeric_limits<double>::infinity();
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d q =
        ClosestPointOnTriangle(p, mesh.vertices[t[0]], mesh.vertices[t[1]], mesh.vertices[t[2]]);
    best = std::min(best, (q - p).squaredNorm());
  }
  return std::sqrt(best);
}

double MeshArea(const TriangleMesh& mesh) {
  double area = 0.0;
  for (const auto& t : mesh.triangles) area += TriangleArea(mesh, t);
  return area;
}

double MeshSignedVolume(const TriangleMesh& mesh) {
  double six_v = 0.0;
  for (const auto& t : mesh.triangles) {
    six_v += mesh.vertices[t[0]].dot(mesh.vertices[t[1]].cross(mesh.vertices[t[2]]));
  }
  return six_v / 6.0;
}

EdgeCounts CountEdges(const TriangleMesh& mesh) {
  std::unordered_map<std::uint64_t, int> uses;
  uses.reserve(mesh.triangles.size() * 2);
  for (const auto& t : mesh.triangles) {
    for (int e = 0; e < 3; ++e) {
      std::uint64_t a = static_cast<std::uint32_t>(t[e]), b = static_cast<std::uint32_t>(t[(e + 1) % 3]);
      if (a > b) std::swap(a, b);
      ++uses[(a << 32) | b];
    }
  }
  EdgeCounts counts;
  counts.total = static_cast<long>(uses.size());
  for (const auto& [edge, n] : uses) {
    if (n == 1) ++counts.boundary;
    if (n > 2) ++counts.non_manifold;
  }
  return counts;
}

void MeshBounds(const TriangleMesh& mesh, Eigen::Vector3d* min, Eigen::Vector3d* max) {
  *min = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  *max = -*min;
  for (const auto& v : mesh.vertices) {
    *min = min->cwiseMin(v);
    *max = max->cwiseMax(v);
  }
}

void ValidateMesh(const TriangleMesh& mesh, const std::string& name) {
  TROCAR_THROW_UNLESS(!mesh.triangles.empty(), name << ": mesh is empty (no triangles)");
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    TROCAR_THROW_UNLESS(mesh.vertices[i].allFinite(),
                        name << ": vertex " << i << " is not finite");
  }
  const int n = static_cast<int>(mesh.vertices.size());
  for (std::size_t i = 0; i < mesh.triangles.size(); ++i) {
    const Eigen::Vector3i& t = mesh.triangles[i];
    TROCAR_THROW_UNLESS((t.array() >= 0).all() && (t.array() < n).all(),
                        name << ": triangle " << i << " indexes a vertex outside 0.." << n - 1);
    TROCAR_THROW_UNLESS(TriangleArea(mesh, t) > 0.0,
                        name << ": triangle " << i << " has zero area");
  }
}

void WriteStl(const TriangleMesh& mesh, const std::string& path, bool mm) {
  const double scale = mm ? 1e3 : 1.0;
  std::string out(80, '\0');
  const std::string header = "trocar " + mesh.source;
  std::memcpy(out.data(), header.data(), std::min<std::size_t>(header.size(), 80));
  auto put_u32 = [&](std::uint32_t v) { out.append(reinterpret_cast<const char*>(&v), 4); };
  auto put_f32 = [&](double v) {
    const float f = static_cast<float>(v);
    out.append(reinterpret_cast<const char*>(&f), 4);
  };
  put_u32(static_cast<std::uint32_t>(mesh.triangles.size()));
  out.reserve(out.size() + 50 * mesh.triangles.size());
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3d &a = mesh.vertices[t[0]], &b = mesh.vertices[t[1]], &c = mesh.vertices[t[2]];
    const Eigen::Vector3d n = (b - a).cross(c - a).normalized();
    for (int i = 0; i < 3; ++i) put_f32(n[i]);
    for (const Eigen::Vector3d* p : {&a, &b, &c}) {
      for (int i = 0; i < 3; ++i) put_f32((*p)[i] * scale);
    }
    out.append(2, '\0');
  }
  WriteFileAtomically(path, out);
}

}  // namespace trocar
