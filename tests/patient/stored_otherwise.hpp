#pragma once
/// Tests' helper: one CT stored with its index axes in another order (a sagittal or coronal
/// stack, reversed axes), the voxels at the same places in the patient.

#include <array>

#include "patient/volume.hpp"

namespace trocar::test {

// The same grid stored with its index axes in another order, some reversed: the stored volume's
// index axis a is `from`'s axis order[a], reversed where flip[a]; voxel (i, j, k) of `from` is
// voxel Index(from, i, j, k) of `ct`, at the same place in the patient.
struct Stored {
  patient::Volume ct;
  std::array<int, 3> order{0, 1, 2};
  std::array<bool, 3> flip{false, false, false};
  long Index(const patient::Volume& from, int i, int j, int k) const {
    const int old_index[3] = {i, j, k};
    int n[3];
    for (int a = 0; a < 3; ++a) {
      const int o = order[a];
      n[a] = flip[a] ? from.size[o] - 1 - old_index[o] : old_index[o];
    }
    return ct.Index(n[0], n[1], n[2]);
  }
};

inline Stored StoreOtherwise(const patient::Volume& from, std::array<int, 3> order,
                             std::array<bool, 3> flip) {
  Stored s;
  s.order = order;
  s.flip = flip;
  s.ct = from;
  Eigen::Vector3i corner = Eigen::Vector3i::Zero();
  for (int a = 0; a < 3; ++a) {
    const int o = order[a];
    s.ct.size[a] = from.size[o];
    s.ct.index_to_P.col(a) = (flip[a] ? -1.0 : 1.0) * from.index_to_P.col(o);
    if (flip[a]) corner[o] = from.size[o] - 1;
  }
  s.ct.origin_P = from.PatientPoint(corner.x(), corner.y(), corner.z());
  for (int k = 0; k < from.size.z(); ++k)
    for (int j = 0; j < from.size.y(); ++j)
      for (int i = 0; i < from.size.x(); ++i)
        s.ct.values[s.Index(from, i, j, k)] = from.values[from.Index(i, j, k)];
  return s;
}

}  // namespace trocar::test
