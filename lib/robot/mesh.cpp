#include "robot/mesh.hpp"

#include <cmath>

#include <assimp/Importer.hpp>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include "common/error.hpp"
#include "common/file_util.hpp"

namespace trocar::robot {
namespace {

// Sub-meshes carry their node transforms; apply them so multi-part files come out assembled.
void CollectNode(const aiScene* scene, const aiNode* node, const aiMatrix4x4& parent,
                 const Eigen::Vector3d& scale, TriangleMesh* out) {
  const aiMatrix4x4 transform = parent * node->mTransformation;
  for (unsigned m = 0; m < node->mNumMeshes; ++m) {
    const aiMesh* mesh = scene->mMeshes[node->mMeshes[m]];
    const int base = static_cast<int>(out->vertices.size());
    for (unsigned v = 0; v < mesh->mNumVertices; ++v) {
      const aiVector3D p = transform * mesh->mVertices[v];
      out->vertices.emplace_back(p.x * scale.x(), p.y * scale.y(), p.z * scale.z());
    }
    for (unsigned f = 0; f < mesh->mNumFaces; ++f) {
      const aiFace& face = mesh->mFaces[f];
      if (face.mNumIndices != 3) continue;  // points and lines carry no surface
      out->triangles.emplace_back(base + static_cast<int>(face.mIndices[0]),
                                  base + static_cast<int>(face.mIndices[1]),
                                  base + static_cast<int>(face.mIndices[2]));
    }
  }
  for (unsigned c = 0; c < node->mNumChildren; ++c) {
    CollectNode(scene, node->mChildren[c], transform, scale, out);
  }
}

}  // namespace

std::shared_ptr<const TriangleMesh> LoadMesh(const std::string& path,
                                             const Eigen::Vector3d& scale) {
  TROCAR_THROW_UNLESS(IsRegularFile(path), path << ": mesh file not found");
  TROCAR_THROW_UNLESS(scale.allFinite() && (scale.array() != 0.0).all(),
                      path << ": mesh scale " << scale.transpose()
                           << " must be finite and non-zero");
  Assimp::Importer importer;
  const aiScene* scene = importer.ReadFile(
      path, aiProcess_Triangulate | aiProcess_JoinIdenticalVertices | aiProcess_SortByPType);
  TROCAR_THROW_UNLESS(scene != nullptr && scene->mRootNode != nullptr,
                      path << ": cannot read mesh: " << importer.GetErrorString());
  auto mesh = std::make_shared<TriangleMesh>();
  mesh->source = path;
  CollectNode(scene, scene->mRootNode, aiMatrix4x4(), scale, mesh.get());
  TROCAR_THROW_UNLESS(!mesh->triangles.empty(), path << ": mesh has no triangles");
  for (std::size_t i = 0; i < mesh->vertices.size(); ++i) {
    TROCAR_THROW_UNLESS(mesh->vertices[i].allFinite(),
                        path << ": vertex " << i << " is not finite");
  }
  // Drop zero-area triangles (common in CAD exports); the count is kept and reported.
  std::vector<Eigen::Vector3i> kept;
  kept.reserve(mesh->triangles.size());
  for (const auto& t : mesh->triangles) {
    if (TriangleArea(*mesh, t) > 0.0) kept.push_back(t);
  }
  mesh->degenerate_triangles_removed = static_cast<int>(mesh->triangles.size() - kept.size());
  mesh->triangles = std::move(kept);
  TROCAR_THROW_UNLESS(!mesh->triangles.empty(),
                      path << ": every triangle of the mesh has zero area");
  return mesh;
}

}  // namespace trocar::robot
