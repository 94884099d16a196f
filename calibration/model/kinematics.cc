// Explicit instantiation of the double versions used outside the autodiff path.
#include "cdpr/calibration/kinematics.hpp"

namespace cdpr {
template CableGeometry<double> cable_geometry<double>(const Vec3<double>&, const Eigen::Matrix3d&,
                                                      const double&, const Vec3<double>&);
}  // namespace cdpr
