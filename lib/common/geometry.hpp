#pragma once
/// @file
/// Small geometry helpers shared by every module. Poses are Eigen::Isometry3d named by frame
/// (Drake's monogram notation): `X_WB` is the pose of frame B measured in frame W.

#include <string>
#include <vector>

#include <Eigen/Geometry>

namespace trocar {

/// Rotation from URDF roll-pitch-yaw (fixed axes X, then Y, then Z): R = Rz(yaw) Ry(pitch) Rx(roll).
Eigen::Matrix3d RotationFromRpy(const Eigen::Vector3d& rpy);

/// Inverse of RotationFromRpy; pitch in [-pi/2, pi/2].
Eigen::Vector3d RpyFromRotation(const Eigen::Matrix3d& R);

/// Pose from a translation and URDF roll-pitch-yaw angles.
Eigen::Isometry3d MakeTransform(const Eigen::Vector3d& xyz, const Eigen::Vector3d& rpy);

/// Elementary transforms used by Denavit-Hartenberg tables.
Eigen::Isometry3d RotX(double angle);
Eigen::Isometry3d RotZ(double angle);
Eigen::Isometry3d TransX(double distance);
Eigen::Isometry3d TransZ(double distance);

/// Angle wrapped into (-pi, pi].
double WrapAngle(double angle);

/// The median of `values` (the mean of the middle two for an even count); NaN when empty.
double Median(std::vector<double> values);

/// Angle between two rotations, in radians (0 .. pi).
double RotationDistance(const Eigen::Matrix3d& R_a, const Eigen::Matrix3d& R_b);

/// Parses a scalar written as a number or a simple angle expression: "1.5", "pi", "-pi/2",
/// "3*pi/4", "90deg", "-30 deg". Returns false (and leaves `value` untouched) when the text is
/// not one of these forms.
bool ParseScalarExpression(const std::string& text, double* value);

/// "[x, y, z]" with the given number of significant digits, for messages and printing.
std::string FormatVector(const Eigen::Ref<const Eigen::VectorXd>& v, int precision = 6);

/// A small error as a person reads it: "under 0.01 mm" below `resolution` (0.01 here), else the
/// value to the resolution's decimals ("0.38 mm"); `value` in the unit named.
std::string FormatError(double value, const char* unit, double resolution = 0.01);

}  // namespace trocar
