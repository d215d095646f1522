#pragma once
/// @file
/// RobotModel: an immutable kinematic tree (links, joints, closures, named frames) shared by
/// every thread; RobotState (robot_state.hpp) holds what changes per query.
///
/// Conventions
/// - SI units: metres, radians, seconds.
/// - A joint's frame J is its child link's frame: X_PC(θ) = X_PJ · Motion(axis_J, θ), as in URDF.
/// - Configuration `q` holds the *active* joints only (the ones a controller drives), in
///   `active_joints()` order. Every movable joint also has a slot in the full joint-value vector
///   (`dof_index`): held passive joints (setup joints), mimic joints and closure-solved joints.
/// - Jacobians stack angular over linear velocity, [ω; v] (Angeles, thesis eq. 4.24), like Drake.

#include <limits>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <Eigen/Geometry>

#include "robot/mesh.hpp"
#include "robot/robot_defaults.hpp"

namespace trocar::robot {

enum class JointType { kFixed, kRevolute, kPrismatic };
const char* ToString(JointType type);

/// How a movable joint gets its value.
enum class JointDrive {
  kActive,   ///< part of q; driven by controllers and planners
  kHeld,     ///< passive, set before use and then held (e.g. da Vinci setup joints)
  kMimic,    ///< value = multiplier · value(master) + offset (URDF <mimic>)
  kClosure,  ///< solved from its closure's driver by the four-bar solver
};
const char* ToString(JointDrive drive);

/// Limits in SI units (m, rad, m/s, rad/s, m/s², rad/s²); infinite when not given.
struct JointLimits {
  double lower = -std::numeric_limits<double>::infinity();
  double upper = std::numeric_limits<double>::infinity();
  double velocity = std::numeric_limits<double>::infinity();
  double acceleration = std::numeric_limits<double>::infinity();
  double effort = std::numeric_limits<double>::infinity();
};

struct Mimic {
  int master = -1;  ///< joint index
  double multiplier = 1.0;
  double offset = 0.0;
};

struct Joint {
  std::string name;
  JointType type = JointType::kFixed;
  int parent_link = -1;
  int child_link = -1;
  Eigen::Isometry3d X_PJ = Eigen::Isometry3d::Identity();  ///< joint frame in the parent link
  Eigen::Vector3d axis_J = Eigen::Vector3d::UnitZ();        ///< unit axis in the joint frame
  JointLimits limits;
  JointDrive drive = JointDrive::kActive;
  Mimic mimic;         ///< valid when drive == kMimic
  int closure = -1;    ///< closure index when drive == kClosure
  int q_index = -1;    ///< position in q when drive == kActive
  int dof_index = -1;  ///< position in the full joint-value vector; -1 for fixed joints
  /// Rodrigues' terms of a revolute joint in its parent (derived from X_PJ and axis_J when the
  /// model is built): R_PC(θ) = R_PJ (cos θ I + sin θ [a]× + (1 − cos θ) a aᵀ)
  /// = cos θ (R_PJ − rodrigues_M) + sin θ rodrigues_N + rodrigues_M, with M = R_PJ a aᵀ and
  /// N = R_PJ [a]×: forward kinematics then needs no matrix product for the joint's rotation.
  Eigen::Matrix3d rodrigues_M = Eigen::Matrix3d::Zero();
  Eigen::Matrix3d rodrigues_N = Eigen::Matrix3d::Zero();

  bool movable() const { return type != JointType::kFixed; }
};

/// Visual or collision shape attached to a link.
struct Geometry {
  enum class Shape { kMesh, kBox, kCylinder, kSphere, kCapsule };
  Shape shape = Shape::kBox;
  /// box: x, y, z sides; cylinder and capsule: radius, length (along z, capsule without caps);
  /// sphere: radius.
  Eigen::Vector3d size = Eigen::Vector3d::Zero();
  std::string mesh_file;  ///< resolved path, for meshes
  Eigen::Vector3d mesh_scale = Eigen::Vector3d::Ones();
  std::shared_ptr<const TriangleMesh> mesh;  ///< loaded mesh (null when loading was skipped)
  Eigen::Isometry3d X_LG = Eigen::Isometry3d::Identity();  ///< shape pose in its link
  Eigen::Vector4d rgba{0.8, 0.8, 0.8, 1.0};
};
const char* ToString(Geometry::Shape shape);

struct Link {
  std::string name;
  int parent_joint = -1;  ///< -1 for the root (base) link
  std::vector<int> child_joints;
  std::vector<Geometry> visuals;
  std::vector<Geometry> collisions;
  /// The body's kinematic frame K in the link frame (thesis §2.4.2): on an active joint, origin
  /// on the joint, z along its axis, x toward the body's own frame; for a body with two passive
  /// joints, origin at their midpoint, z along the second joint's axis, x from the first joint
  /// toward the second; otherwise the link frame itself (the body moves welded to its parent).
  Eigen::Isometry3d X_LK = Eigen::Isometry3d::Identity();
};

/// A named frame fixed to a link: the tool, the remote centre of motion, markers.
struct Frame {
  std::string name;
  int link = -1;
  Eigen::Isometry3d X_LF = Eigen::Isometry3d::Identity();
};

/// A planar four-bar loop closed over a kinematic tree (thesis appendix A, generalised).
///
/// Ground link G carries the driver joint (G → crank A) and the rocker joint (G → rocker B); the
/// coupler joint connects crank A → coupler C. The loop is closed by a cut joint between C and B
/// whose axis passes through `p_C3` (in C) and `p_B3` (in B). All four axes are parallel and the
/// loop is assembled at the zero configuration. Given the driver's value the solver finds the
/// coupler's and rocker's values, keeping link lengths and refusing to pass a change point
/// (where the mechanism could invert).
struct FourBarClosure {
  std::string name;
  int driver = -1;
  int coupler = -1;
  int rocker = -1;
  Eigen::Vector3d p_C3 = Eigen::Vector3d::Zero();
  Eigen::Vector3d p_B3 = Eigen::Vector3d::Zero();

  // Planar data in the ground link frame, derived when the model is built.
  int ground_link = -1;
  Eigen::Vector3d n_G, u_G, v_G;  ///< plane normal (driver axis) and in-plane basis
  Eigen::Vector2d P1, c0, P4;     ///< driver axis, crank vector at zero, rocker axis
  double L23 = 0.0;               ///< coupler length (coupler axis → cut axis)
  double L34 = 0.0;               ///< rocker length (rocker axis → cut axis)
  double coupler_ref_angle = 0.0; ///< in-plane angle of P3 − P2 at zero coupler value, θ_d = 0
  double rocker_ref_angle = 0.0;  ///< in-plane angle of P3 − P4 at zero rocker value
  double coupler_sign = 1.0;      ///< +1 when the coupler axis points along n_G, else −1
  double rocker_sign = 1.0;
  double branch_sign = 1.0;       ///< side of line P2→P4 on which P3 lies (kept, never flipped)
  /// Driver values where |P4 − P2| is extremal are k π − change_phase (the crank aligned with
  /// P1→P4); undefined (0) when P1 = P4.
  double change_phase = 0.0;
};

class RobotModelBuilder;

/// Immutable robot description. Build one with RobotModelBuilder or a loader (load_robot.hpp).
class RobotModel {
 public:
  const std::string& name() const { return name_; }
  /// The file the model was loaded from (for messages), or "" for models made in code.
  const std::string& source() const { return source_; }

  int num_links() const { return static_cast<int>(links_.size()); }
  int num_joints() const { return static_cast<int>(joints_.size()); }
  /// Size of q: the active joints.
  int num_positions() const { return static_cast<int>(active_joints_.size()); }
  /// Number of movable joints (active and passive).
  int num_dofs() const { return static_cast<int>(dof_joints_.size()); }

  /// Links in depth-first order from the base: a parent always precedes its children.
  const Link& link(int index) const { return links_.at(index); }
  /// Joints in depth-first order: a joint's parent link is placed before the joint.
  const Joint& joint(int index) const { return joints_.at(index); }
  const std::vector<Link>& links() const { return links_; }
  const std::vector<Joint>& joints() const { return joints_; }

  /// Joint index of each entry of q.
  const std::vector<int>& active_joints() const { return active_joints_; }
  /// Joint index of each movable joint, by dof_index.
  const std::vector<int>& dof_joints() const { return dof_joints_; }
  const std::vector<FourBarClosure>& closures() const { return closures_; }

  /// Order in which passive (mimic, closure) joints are resolved from q: entries are joint
  /// indices for mimic joints and −1 − closure_index for closures.
  const std::vector<int>& resolve_order() const { return resolve_order_; }

  int base_link() const { return 0; }
  const Frame& tool_frame() const { return tool_; }
  /// How the tool was chosen: "declared", "the link named 'tool'", or the chain it ends.
  const std::string& tool_basis() const { return tool_basis_; }
  /// Remote centre of motion, when the robot has one (mechanical or declared).
  const std::optional<Frame>& rcm_frame() const { return rcm_; }
  /// Every named frame, the tool (and RCM) included. Links are frames too (GetFrame finds them
  /// by name), but are not listed here.
  const std::vector<Frame>& frames() const { return frames_; }

  /// Index by name, or -1.
  int FindLink(const std::string& name) const;
  int FindJoint(const std::string& name) const;
  /// Index by name. @throws trocar::Error listing the known names when absent.
  int GetLink(const std::string& name) const;
  int GetJoint(const std::string& name) const;
  /// A named frame, or else a link by name (its own frame). @throws listing both when absent.
  const Frame& GetFrame(const std::string& name) const;

  /// Movable joints on the path from the base to `link`, base first.
  const std::vector<int>& movable_path(int link) const { return movable_paths_.at(link); }

  /// Limits of q as vectors (for controllers and planners).
  Eigen::VectorXd lower_limits() const;
  Eigen::VectorXd upper_limits() const;
  Eigen::VectorXd velocity_limits() const;
  Eigen::VectorXd acceleration_limits() const;
  /// A configuration inside the limits: 0 where allowed, otherwise the middle of the range.
  Eigen::VectorXd neutral_configuration() const;

  /// What the description suggests for using the robot (home, controller gains): a part apart
  /// from the kinematics, which never read it.
  const RobotDefaults& defaults() const { return defaults_; }

 private:
  friend class RobotModelBuilder;
  RobotModel() = default;
  Eigen::VectorXd ActiveLimits(double JointLimits::*member) const;

  std::string name_;
  std::string source_;
  std::vector<Link> links_;
  std::vector<Joint> joints_;
  std::vector<int> active_joints_;
  std::vector<int> dof_joints_;
  std::vector<FourBarClosure> closures_;
  std::vector<int> resolve_order_;
  std::vector<std::vector<int>> movable_paths_;
  Frame tool_;
  std::string tool_basis_;
  std::optional<Frame> rcm_;
  std::vector<Frame> frames_;
  std::vector<Frame> link_frames_;  // one per link, at the link's origin
  RobotDefaults defaults_;
};

/// Collects a robot description by name and turns it into a validated RobotModel. Loaders (URDF,
/// DH YAML, the trocar sidecar) fill it; Build() checks everything and resolves names, throwing
/// trocar::Error messages that start with the source file and name the element.
class RobotModelBuilder {
 public:
  struct LinkSpec {
    std::string name;
    std::vector<Geometry> visuals;
    std::vector<Geometry> collisions;
  };
  struct JointSpec {
    std::string name;
    JointType type = JointType::kFixed;
    std::string parent;
    std::string child;
    Eigen::Isometry3d X_PJ = Eigen::Isometry3d::Identity();
    Eigen::Vector3d axis = Eigen::Vector3d::UnitZ();
    JointLimits limits;
    std::optional<std::string> mimic_master;
    double mimic_multiplier = 1.0;
    double mimic_offset = 0.0;
    bool held = false;  ///< passive, set before use
  };
  struct FourBarSpec {
    std::string name;
    std::string driver, coupler, rocker;
    Eigen::Vector3d p_C3 = Eigen::Vector3d::Zero();
    std::optional<Eigen::Vector3d> p_B3;  ///< derived from the zero configuration when absent
  };
  struct FrameSpec {
    std::string name;
    std::string link;
    Eigen::Isometry3d X_LF = Eigen::Isometry3d::Identity();
  };

  RobotModelBuilder(std::string name, std::string source);

  const std::string& source() const { return source_; }
  void set_name(const std::string& name) { name_ = name; }

  /// @throws trocar::Error on a duplicate name.
  LinkSpec& AddLink(const std::string& name);
  JointSpec& AddJoint(const std::string& name);
  LinkSpec* FindLink(const std::string& name);
  JointSpec* FindJoint(const std::string& name);
  /// @throws trocar::Error naming the element when absent.
  LinkSpec& GetLink(const std::string& name);
  JointSpec& GetJoint(const std::string& name);
  const std::vector<JointSpec>& joints() const { return joints_; }
  const std::vector<LinkSpec>& links() const { return links_; }

  void AddFourBar(FourBarSpec spec) { four_bars_.push_back(std::move(spec)); }
  /// Restricts q to these joints, in this order; other plain movable joints become held.
  void SetActiveJoints(std::vector<std::string> names) { active_order_ = std::move(names); }
  void SetTool(FrameSpec tool) { tool_ = std::move(tool); }
  void SetRcm(FrameSpec rcm) { rcm_ = std::move(rcm); }
  void AddFrame(FrameSpec frame) { frames_.push_back(std::move(frame)); }
  const std::vector<FrameSpec>& frames() const { return frames_; }
  /// Gains for the model's defaults (checked by Build: six finite, non-negative values each).
  ControllerSettings& controller() { return controller_; }
  /// Active joint values (in q order) where sessions start; checked against the limits.
  void SetHome(std::vector<double> home) { home_ = std::move(home); }
  /// Meshes of another description for some links to wear where drawn (names checked here).
  void AddAppearance(Appearance appearance);

  /// Copies every element of `other` into this description with names prefixed by `prefix`:
  /// links, joints (mimic masters and held flags included), closures, frames; its tool and RCM
  /// become frames `<prefix>tool` and `<prefix>rcm`, and its active-joint list (when it has one)
  /// is appended to this one's. With a `parent_link`, other's root is attached to it by a fixed
  /// joint `<prefix>mount` at X_PC; without one, other becomes this description's base and also
  /// lends its tool, RCM and controller settings where this one has none.
  /// @throws trocar::Error on name clashes or an unknown parent link.
  void Attach(const RobotModelBuilder& other, const std::string& prefix,
              const std::string& parent_link, const Eigen::Isometry3d& X_PC);

  /// Validates and builds, in named stages (each below, each throwing errors that name the
  /// source and the element): the tree, links and joints, drives, closures, active joints,
  /// resolution order, kinematic frames, movable paths, named frames, defaults. Default tool
  /// frame: a link named 'tool', else the tip of the chain below the last active joint,
  /// followed through fixed and mimic joints while the chain does not branch.
  RobotModel Build() const;

 private:
  struct TreeOrder {
    std::vector<int> links, joints;  ///< spec indices, depth first from the root
  };
  struct NameIndex {
    std::map<std::string, int> links, joints;  ///< name → index in the model
  };
  TreeOrder ValidateTree() const;
  NameIndex AddLinksAndJoints(const TreeOrder& order, RobotModel* model) const;
  int MovableJoint(const NameIndex& names, const RobotModel& model, const std::string& name,
                   const std::string& role) const;
  void AssignDrives(const TreeOrder& order, const NameIndex& names, RobotModel* model) const;
  void BuildClosures(const NameIndex& names, RobotModel* model) const;
  void AssignActiveJoints(const NameIndex& names, RobotModel* model) const;
  void OrderResolution(RobotModel* model) const;
  void AddKinematicFrames(RobotModel* model) const;
  void AddMovablePaths(RobotModel* model) const;
  void AddNamedFrames(const NameIndex& names, RobotModel* model) const;
  void SetDefaults(RobotModel* model) const;

  std::string name_;
  std::string source_;
  std::vector<LinkSpec> links_;
  std::vector<JointSpec> joints_;
  std::vector<FourBarSpec> four_bars_;
  std::optional<std::vector<std::string>> active_order_;
  std::optional<FrameSpec> tool_;
  std::optional<FrameSpec> rcm_;
  std::vector<FrameSpec> frames_;
  ControllerSettings controller_;
  std::optional<std::vector<double>> home_;
  std::vector<Appearance> appearances_;
};

}  // namespace trocar::robot
