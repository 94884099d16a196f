#include "cdpr/calibration/identifiability.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <limits>
#include <sstream>

#include "identification_internal.hpp"

namespace cdpr {

namespace {

// Words for a parameter ({kLengthOffset, 2} -> "the length offset of cable 3").
std::string words(const ParameterId& id) {
  const std::string cable = std::to_string(id.index + 1);
  switch (id.kind) {
    case ParameterKind::kLengthOffset:
      return "the length offset of cable " + cable;
    case ParameterKind::kLengthScale:
      return "the transmission scale of cable " + cable;
    case ParameterKind::kStiffness:
      return id.index < 0 ? "the shared cable stiffness EA" : "the stiffness EA of cable " + cable;
    case ParameterKind::kForceGain:
      return "the force sensor gain of cable " + cable;
    case ParameterKind::kForceOffset:
      return "the force sensor offset of cable " + cable;
    case ParameterKind::kPlatformAnchor:
      return parameter_name(id) + " (platform anchor)";
    case ParameterKind::kSwivelZero:
      return "the swivel encoder zero of cable " + cable;
    case ParameterKind::kInclinometerMount:
      return id.component == 0 ? "the inclinometer's mounting roll"
                               : "the inclinometer's mounting pitch";
    case ParameterKind::kImuYawZero:
      return "the IMU's heading zero";
    case ParameterKind::kPlatformMass:
      return "the platform mass";
    case ParameterKind::kPlatformCom:
      return id.component == 2 ? "the height of the platform's centre of mass (seen only in "
                                 "tilted poses: record poses with roll or pitch)"
                               : "the platform's centre of mass " + parameter_name(id);
    default:
      return parameter_name(id);
  }
}

struct Named {
  std::string text;
  double weight;
};

// Names the main components of the unit direction v (column-normalised coordinates); `delta` is
// the same direction in SI parameter units.
std::vector<Named> components(const GeometryInformation& gi, const Eigen::VectorXd& v,
                              const Eigen::VectorXd& delta, const IdentifiabilityOptions& opt) {
  std::vector<Named> out;
  const int P = static_cast<int>(v.size());
  std::vector<bool> used(static_cast<std::size_t>(P), false);
  const int m = static_cast<int>(gi.anchor_columns.cols());
  for (int i = 0; i < m; ++i) {
    Eigen::Vector3d w_si = Eigen::Vector3d::Zero();
    double importance2 = 0.0;
    int count = 0;
    int biggest = -1;
    double big = 0.0;
    for (int q = 0; q < 3; ++q) {
      const int col = gi.anchor_columns(q, i);
      if (col < 0) continue;
      used[static_cast<std::size_t>(col)] = true;
      w_si(q) = delta(col);
      importance2 += v(col) * v(col);
      ++count;
      if (std::abs(v(col)) > big) {
        big = std::abs(v(col));
        biggest = q;
      }
    }
    if (count == 0) continue;
    const double importance = std::sqrt(importance2);
    if (importance < opt.component_threshold) continue;
    const std::string a = parameter_name({ParameterKind::kFrameAnchor, i, -1});  // "a_3"
    const Eigen::Vector3d u = gi.home_cable_directions.col(i);
    const double along = w_si.dot(u);
    // Sign convention: "+" moves the anchor away from the platform along its cable.
    if (count == 3 && along * along >= 0.8 * w_si.squaredNorm()) {
      out.push_back(
          {a + " along cable " + std::to_string(i + 1), along > 0 ? importance : -importance});
    } else if (big * big >= 0.8 * importance2) {
      out.push_back({parameter_name({ParameterKind::kFrameAnchor, i, biggest}),
                     v(gi.anchor_columns(biggest, i))});
    } else {
      char buf[96];
      const Eigen::Vector3d dir = w_si.normalized();
      std::snprintf(buf, sizeof(buf), "%s along (%.2f, %.2f, %.2f)", a.c_str(), dir.x(), dir.y(),
                    dir.z());
      out.push_back({buf, importance});
    }
  }
  for (int q = 0; q < P; ++q) {
    if (used[static_cast<std::size_t>(q)]) continue;
    if (std::abs(v(q)) < opt.component_threshold) continue;
    out.push_back({words(gi.ids[static_cast<std::size_t>(q)]), v(q)});
  }
  std::sort(out.begin(), out.end(),
            [](const Named& x, const Named& y) { return std::abs(x.weight) > std::abs(y.weight); });
  if (static_cast<int>(out.size()) > opt.max_components) {
    out.resize(static_cast<std::size_t>(opt.max_components));
  }
  return out;
}

// True when the anchor part of `delta` is a rigid motion of the whole frame carrying most of v.
bool is_gauge(const GeometryInformation& gi, const Eigen::VectorXd& v, const Eigen::VectorXd& delta,
              std::string* what) {
  const int m = static_cast<int>(gi.anchor_columns.cols());
  if (m == 0 || gi.frame_anchors.cols() != m) return false;
  double anchor_importance = 0.0;
  Eigen::VectorXd d = Eigen::VectorXd::Zero(3 * m);
  for (int i = 0; i < m; ++i) {
    for (int q = 0; q < 3; ++q) {
      const int col = gi.anchor_columns(q, i);
      if (col < 0) continue;
      d(3 * i + q) = delta(col);
      anchor_importance += v(col) * v(col);
    }
  }
  if (anchor_importance < 0.5 || d.norm() == 0.0) return false;
  // delta a_i = t + w x a_i = t - [a_i]x w
  Eigen::MatrixXd G(3 * m, 6);
  for (int i = 0; i < m; ++i) {
    const Eigen::Vector3d a = gi.frame_anchors.col(i);
    Eigen::Matrix3d ax;
    ax << 0, -a.z(), a.y(), a.z(), 0, -a.x(), -a.y(), a.x(), 0;
    G.block<3, 3>(3 * i, 0) = Eigen::Matrix3d::Identity();
    G.block<3, 3>(3 * i, 3) = -ax;
  }
  const Eigen::VectorXd x = G.colPivHouseholderQr().solve(d);
  if ((G * x - d).norm() > 0.1 * d.norm()) return false;
  const Eigen::Vector3d t = x.head<3>(), w = x.tail<3>();
  char buf[400];
  // Express the translation in metres per unit rotation scale for the words.
  const double scale = std::max(1e-12, d.norm());
  if (gi.home_pose_fixed) {
    // The home pose is held already: the readings do not see this motion (a rigid motion of the
    // frame about the held pose, e.g. a turn about the vertical that no reading depends on).
    std::snprintf(buf, sizeof(buf),
                  "the whole frame moves rigidly (translation %.2f %.2f %.2f, rotation %.2f %.2f "
                  "%.2f) and the held home pose does not stop it: no reading of these poses sees "
                  "this motion; measure poses spread in position and heading, add a channel that "
                  "sees it (swivel encoders, an IMU heading, a laser) or estimate fewer anchor "
                  "coordinates",
                  t.x() / scale, t.y() / scale, t.z() / scale, w.x() / scale, w.y() / scale,
                  w.z() / scale);
  } else {
    std::snprintf(buf, sizeof(buf),
                  "gauge freedom: the whole frame moves rigidly with the poses (translation "
                  "%.2f %.2f %.2f, rotation %.2f %.2f %.2f); fix the home pose or anchor "
                  "coordinates",
                  t.x() / scale, t.y() / scale, t.z() / scale, w.x() / scale, w.y() / scale,
                  w.z() / scale);
  }
  *what = buf;
  return true;
}

}  // namespace

IdentifiabilityReport analyze_identifiability(const GeometryInformation& gi,
                                              const IdentifiabilityOptions& opt) {
  IdentifiabilityReport r;
  const Eigen::MatrixXd& S = gi.information;
  const int P = static_cast<int>(S.rows());
  r.parameter_ids = gi.ids;
  r.parameter_names = gi.names;
  r.num_parameters = P;
  r.num_residuals = gi.num_residuals;
  if (P == 0) return r;
  // SI singular values.
  {
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(S, Eigen::EigenvaluesOnly);
    r.singular_values = es.eigenvalues().cwiseMax(0.0).cwiseSqrt().reverse();
  }
  Eigen::VectorXd d(P);
  for (int q = 0; q < P; ++q) {
    if (S(q, q) > 0) {
      d(q) = std::sqrt(S(q, q));
    } else {
      d(q) = 1.0;
      r.unobserved.push_back(q);
    }
  }
  const Eigen::MatrixXd N = d.cwiseInverse().asDiagonal() * S * d.cwiseInverse().asDiagonal();
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(N);
  const Eigen::VectorXd sig = es.eigenvalues().cwiseMax(0.0).cwiseSqrt();  // ascending
  r.normalized_singular_values = sig.reverse();
  const double smax = sig.maxCoeff();
  r.rank = 0;
  for (int q = 0; q < P; ++q) r.rank += sig(q) > opt.rank_tolerance * smax ? 1 : 0;
  r.condition_number = r.rank == P ? smax / sig(0) : std::numeric_limits<double>::infinity();
  // Indices on SI values.
  const Eigen::VectorXd& s = r.singular_values;
  const double s1 = s(0), sl = s(P - 1);
  double logsum = 0.0, invsum = 0.0;
  bool zero = false;
  for (int q = 0; q < P; ++q) {
    if (!(s(q) > 0)) {
      zero = true;
      break;
    }
    logsum += std::log(s(q));
    invsum += 1.0 / s(q);
  }
  r.o1 = zero ? 0.0 : std::exp(logsum / P) / std::sqrt(std::max(1, gi.num_residuals));
  r.o2 = s1 > 0 ? sl / s1 : 0.0;
  r.o3 = sl;
  r.o4 = s1 > 0 ? sl * sl / s1 : 0.0;
  r.o5 = zero ? 0.0 : 1.0 / invsum;
  // The gauge in words.
  {
    const auto& c = gi.channel_rows;
    const bool gravity = c.wrench > 0 || c.inclination > 0;
    std::string what;
    if (gi.home_pose_fixed) what = "the home pose (held fixed)";
    if (gi.home_tilt_free) {
      what = "the home pose's position and heading (held fixed; its roll and pitch estimated)";
    }
    if (c.laser > 0) what += std::string(what.empty() ? "" : ", ") + "the laser target plane";
    if (c.reference > 0) what += std::string(what.empty() ? "" : ", ") + "reference poses";
    if (c.imu_yaw > 0) what += std::string(what.empty() ? "" : ", ") + "the IMU heading (yaw)";
    if (gravity) {
      what += std::string(what.empty() ? "" : " and ") + "gravity (" +
              (c.wrench > 0 && c.inclination > 0 ? "equilibrium and inclinometer"
               : c.wrench > 0                    ? "equilibrium"
                                                 : "inclinometer") +
              ": the frame's tilt)";
    }
    r.notes.push_back("world frame fixed by " + (what.empty() ? std::string("nothing") : what));
    if (gi.home_tilt_free) {
      r.notes.push_back(
          "suspended robot with fewer than six cables: the equilibrium residuals fix the pose "
          "coordinates the lengths leave free and, with gravity, the world frame's tilt; what "
          "stays in the gauge is the frame's translation (x, y, z) and heading (rotation about "
          "gravity), held by the home pose's position and yaw");
    }
    if (c.laser == 0 && c.reference == 0) {
      r.notes.push_back(
          "no laser or tracker: the world frame is fixed by the home pose and gravity only; the "
          "anchors are found relative to where the platform is at home, and an error in the "
          "home pose moves every anchor with it");
    }
  }
  // Directions (ascending order = weakest first).
  for (int q = 0; q < P; ++q) {
    if (!(sig(q) <= opt.weak_tolerance * smax)) break;
    ParameterDirection dir;
    dir.singular_value = sig(q);
    dir.null = sig(q) <= opt.rank_tolerance * smax;
    const Eigen::VectorXd v = es.eigenvectors().col(q);
    Eigen::VectorXd delta = d.cwiseInverse().asDiagonal() * v;
    delta /= std::max(1e-300, delta.norm());
    std::string gauge_text;
    dir.gauge = is_gauge(gi, v, delta, &gauge_text);
    const std::vector<Named> comps = components(gi, v, delta, opt);
    for (const Named& c : comps) dir.components.push_back({c.text, c.weight});
    if (dir.gauge) {
      dir.description = gauge_text;
    } else if (comps.empty()) {
      dir.description = "a spread combination of many parameters";
    } else if (comps.size() == 1) {
      dir.description = comps[0].text + " is not determined by the data";
    } else {
      std::ostringstream os;
      char w[32];
      std::snprintf(w, sizeof(w), " (%+.2f)", comps[0].weight);
      os << comps[0].text << w << " trades against ";
      for (std::size_t k = 1; k < comps.size(); ++k) {
        if (k > 1) os << (k + 1 == comps.size() ? " and " : ", ");
        std::snprintf(w, sizeof(w), " (%+.2f)", comps[k].weight);
        os << comps[k].text << w;
      }
      dir.description = os.str();
    }
    r.directions.push_back(std::move(dir));
  }
  return r;
}

Result<IdentifiabilityReport> analyze_identifiability(const CalibratedModel& model,
                                                      const MeasurementSet& set,
                                                      const IdentificationOptions& identification,
                                                      const IdentifiabilityOptions& options) {
  std::vector<Pose> poses;
  for (const PoseMeasurement& pm : set.poses) poses.push_back(start_of(pm));
  // Only the total information is analysed: no per-pose matrices (a gigabyte on 100,000 poses).
  auto gi = ident_detail::total_geometry_information(model, set, poses, identification);
  if (!gi) return gi.status();
  IdentifiabilityReport report = analyze_identifiability(*gi, options);
  // Each channel present, left out in turn.
  const auto& c = gi->channel_rows;
  struct Variant {
    const char* name;
    int rows;
    bool IdentificationOptions::*use;
  };
  const Variant variants[] = {
      {"cable lengths", c.length, &IdentificationOptions::use_lengths},
      {"laser", c.laser, &IdentificationOptions::use_laser},
      {"equilibrium", c.wrench, &IdentificationOptions::use_equilibrium},
      {"swivel angles", c.swivel, &IdentificationOptions::use_swivel},
      {"inclinometer", c.inclination, &IdentificationOptions::use_inclinometer},
      {"IMU yaw", c.imu_yaw, &IdentificationOptions::use_imu_yaw},
  };
  const int P = static_cast<int>(gi->ids.size());
  auto stds = [&](const Eigen::MatrixXd& S) {
    const int n = static_cast<int>(S.rows());
    if (n == 0) return Eigen::VectorXd();  // nothing estimated without the channel
    Eigen::VectorXd d(n);
    for (int q = 0; q < n; ++q) d(q) = S(q, q) > 0 ? std::sqrt(S(q, q)) : 1.0;
    const Eigen::MatrixXd N = d.cwiseInverse().asDiagonal() * S * d.cwiseInverse().asDiagonal();
    const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(N);
    const double lmax = es.eigenvalues().maxCoeff();
    Eigen::VectorXd out(n);
    Eigen::VectorXd inv = Eigen::VectorXd::Zero(n);
    std::vector<int> nulls;
    for (int q = 0; q < n; ++q) {
      const double lam = es.eigenvalues()(q);
      if (lmax > 0 && lam > 0 && std::sqrt(lam / lmax) > options.rank_tolerance) {
        inv(q) = 1.0 / lam;
      } else {
        nulls.push_back(q);
      }
    }
    const Eigen::MatrixXd Ninv =
        es.eigenvectors() * inv.asDiagonal() * es.eigenvectors().transpose();
    for (int q = 0; q < n; ++q) {
      double in_null = 0.0;
      for (const int k : nulls) in_null += es.eigenvectors()(q, k) * es.eigenvectors()(q, k);
      out(q) = (in_null > 1e-2 || !(S(q, q) > 0)) ? std::numeric_limits<double>::infinity()
                                                  : std::sqrt(std::max(0.0, Ninv(q, q))) / d(q);
    }
    return out;
  };
  const Eigen::VectorXd with = stds(gi->information);
  for (const Variant& v : variants) {
    if (v.rows == 0 || P == 0) continue;
    IdentificationOptions without = identification;
    without.*(v.use) = false;
    auto g2 = ident_detail::total_geometry_information(model, set, poses, without);
    if (!g2) continue;
    ChannelContribution cc;
    cc.channel = v.name;
    cc.rows = v.rows;
    const IdentifiabilityReport r2 = analyze_identifiability(*g2, options);
    cc.rank_without = r2.rank;  // of the parameters still estimated without the channel
    // Without the channel, parameters only it observes are not estimated at all (the
    // identification frees a mounting parameter only where its channel is used): they count as
    // unidentifiable without it, and the rank is that of the full choice minus them.
    const int P2 = static_cast<int>(g2->ids.size());
    const Eigen::VectorXd wo2 = stds(g2->information);
    Eigen::VectorXd wo = Eigen::VectorXd::Constant(P, std::numeric_limits<double>::infinity());
    for (int q2 = 0; q2 < P2; ++q2) {
      const auto it =
          std::find(gi->ids.begin(), gi->ids.end(), g2->ids[static_cast<std::size_t>(q2)]);
      if (it != gi->ids.end()) wo(static_cast<int>(it - gi->ids.begin())) = wo2(q2);
    }
    std::vector<std::pair<std::string, double>> gains;
    for (int q = 0; q < P; ++q) {
      if (!std::isfinite(with(q))) continue;
      const double ratio =
          std::isfinite(wo(q)) ? wo(q) / with(q) : std::numeric_limits<double>::infinity();
      if (ratio > 1.1) gains.emplace_back(gi->names[static_cast<std::size_t>(q)], ratio);
    }
    std::stable_sort(gains.begin(), gains.end(),
                     [](const auto& x, const auto& y) { return x.second > y.second; });
    int unidentifiable_without = 0;
    for (const auto& g : gains) unidentifiable_without += std::isinf(g.second) ? 1 : 0;
    std::ostringstream os;
    os << v.name << " (" << v.rows << " rows): ";
    if (gains.empty()) {
      os << "adds little (no parameter's bound improves by more than 10 %)";
    } else {
      if (unidentifiable_without > 0) {
        os << "makes " << unidentifiable_without << " parameter"
           << (unidentifiable_without == 1 ? "" : "s") << " identifiable (rank " << r2.rank
           << " -> " << report.rank << ")";
      }
      const std::size_t shown = std::min<std::size_t>(gains.size(), 4);
      os << (unidentifiable_without > 0 ? "; " : "") << "sharpens";
      for (std::size_t k = 0; k < shown; ++k) {
        char buf[96];
        if (std::isinf(gains[k].second)) {
          std::snprintf(buf, sizeof(buf), " %s (from unidentifiable)", gains[k].first.c_str());
        } else {
          std::snprintf(buf, sizeof(buf), " %s (x%.1f)", gains[k].first.c_str(), gains[k].second);
        }
        os << (k ? "," : "") << buf;
      }
      if (gains.size() > shown) os << " and " << gains.size() - shown << " more";
    }
    cc.description = os.str();
    cc.gains = std::move(gains);
    report.channels.push_back(std::move(cc));
  }
  return report;
}

Status require_identifiable(const IdentifiabilityReport& report) {
  if (report.identifiable()) return Status::success();
  std::string msg = "unidentifiable parameter choice (rank " + std::to_string(report.rank) +
                    " of " + std::to_string(report.num_parameters) + "): ";
  int null_count = 0;
  for (const ParameterDirection& d : report.directions) null_count += d.null ? 1 : 0;
  bool first = true;
  for (const ParameterDirection& d : report.directions) {
    if (!d.null) continue;
    if (!first) msg += "; ";
    msg += d.description;
    first = false;
    if (msg.size() > Status::kMaxMessage) break;
  }
  if (msg.size() > Status::kMaxMessage - 1) {
    msg.resize(Status::kMaxMessage - 16);
    msg += " ... (" + std::to_string(null_count) + " dirs)";
  }
  return Status(ErrorCode::kFailedPrecondition, msg);
}

std::string IdentifiabilityReport::summary() const {
  std::ostringstream os;
  char buf[256];
  std::snprintf(buf, sizeof(buf),
                "Identifiability: %d parameters, %d residuals, rank %d, condition number %.4g\n",
                num_parameters, num_residuals, rank, condition_number);
  os << buf;
  std::snprintf(buf, sizeof(buf), "  O1 %.4g  O2 %.4g  O3 %.4g  O4 %.4g  O5 %.4g (SI)\n", o1, o2,
                o3, o4, o5);
  os << buf;
  for (const std::string& n : notes) os << "  " << n << "\n";
  for (const ChannelContribution& c : channels) os << "  channel " << c.description << "\n";
  for (int q : unobserved) {
    os << "  not observed at all: " << parameter_names[static_cast<std::size_t>(q)] << "\n";
  }
  for (const ParameterDirection& d : directions) {
    std::snprintf(buf, sizeof(buf), "  %s direction (sigma %.3g): ", d.null ? "NULL" : "weak",
                  d.singular_value);
    os << buf << d.description << "\n";
  }
  return os.str();
}

}  // namespace cdpr
