#include "cdpr/calibration/model_validation.hpp"

#include <cmath>
#include <cstdio>

#include "cdpr/calibration/winch.hpp"

namespace cdpr {

MeasurementSet tensions_read_with(const MeasurementSet& set, const RobotModel& made_with,
                                  const RobotModel& read_with) {
  MeasurementSet out = set;
  const auto m = made_with.force_sensors.size();
  if (read_with.force_sensors.size() != m) return out;
  for (PoseMeasurement& pm : out.poses) {
    if (static_cast<std::size_t>(pm.tensions.size()) != m) continue;
    for (std::size_t i = 0; i < m; ++i) {
      const ForceSensorModel& a = made_with.force_sensors[i];
      const ForceSensorModel& b = read_with.force_sensors[i];
      if (a.gain == b.gain && a.offset == b.offset) continue;
      const auto k = static_cast<Eigen::Index>(i);
      pm.tensions(k) = (a.gain * pm.tensions(k) + a.offset - b.offset) / b.gain;
    }
  }
  return out;
}

ReadingModel readings_of(const RobotModel& model, const RobotModel& made_with) {
  const int m = model.num_cables();
  ReadingModel r = ReadingModel::nominal(m);
  if (made_with.num_cables() != m) return r;
  for (int i = 0; i < m; ++i) {
    const WinchModel& w0 = made_with.winches[static_cast<std::size_t>(i)];
    const WinchModel& w1 = model.winches[static_cast<std::size_t>(i)];
    const double k0 = winch_length_change<double>(w0, 1.0);
    const double k1 = winch_length_change<double>(w1, 1.0);
    if (!(std::isfinite(k0) && std::isfinite(k1)) || k0 == 0.0) continue;
    // counts = (reading - offset0) / k0; unstretched = offset1 + k1 counts.
    r.length_scales(i) = k1 / k0 - 1.0;
    r.length_offsets(i) = w1.length_offset - (k1 / k0) * w0.length_offset;
  }
  return r;
}

namespace {

// RMS of the finite entries of `values` (their count in `rows`).
double rms_of(const std::vector<double>& values, int* rows) {
  double s = 0.0;
  int n = 0;
  for (const double v : values) {
    if (!std::isfinite(v)) continue;
    s += v * v;
    ++n;
  }
  *rows = n;
  return n ? std::sqrt(s / n) : 0.0;
}

// The per-channel figures of a fit (the channels with rows only).
std::vector<ChannelPrediction> channels_of(const IdentificationReport& r) {
  struct Acc {
    const char* channel;
    const char* unit;
    std::vector<double> si, normalized;
  };
  Acc acc[] = {{"cable lengths", "m", {}, {}}, {"laser", "m", {}, {}},
               {"equilibrium", "N", {}, {}},   {"swivel angles", "rad", {}, {}},
               {"inclination", "rad", {}, {}}, {"IMU yaw", "rad", {}, {}}};
  auto add = [](Acc& a, const Eigen::VectorXd& si, const Eigen::VectorXd& nz) {
    for (Eigen::Index q = 0; q < nz.size(); ++q) {
      a.normalized.push_back(nz(q));
      a.si.push_back(q < si.size() ? si(q) : std::nan(""));
    }
  };
  for (const PoseResiduals& pr : r.residuals) {
    add(acc[0], pr.length_m, pr.length_normalized);
    add(acc[1], pr.laser_m, pr.laser_normalized);
    for (int q = 0; q < 6; ++q) {
      acc[2].normalized.push_back(pr.wrench_normalized(q));
      acc[2].si.push_back(q < 3 ? pr.wrench_si(q) : std::nan(""));  // forces only, N
    }
    add(acc[3], pr.swivel_rad, pr.swivel_normalized);
    add(acc[4], pr.inclination_rad, pr.inclination_normalized);
    add(acc[5], Eigen::VectorXd::Constant(1, pr.imu_yaw_rad),
        Eigen::VectorXd::Constant(1, pr.imu_yaw_normalized));
  }
  std::vector<ChannelPrediction> out;
  for (const Acc& a : acc) {
    ChannelPrediction c;
    c.channel = a.channel;
    c.unit = a.unit;
    int si_rows = 0;
    c.rms_normalized = rms_of(a.normalized, &c.rows);
    c.rms = rms_of(a.si, &si_rows);
    if (c.rows > 0) out.push_back(std::move(c));
  }
  return out;
}

}  // namespace

Result<ModelPrediction> predict_recording(const RobotModel& model, const RobotModel& made_with,
                                          const MeasurementSet& set,
                                          const IdentificationOptions& channels) {
  IdentificationOptions fixed = channels;
  for (const EstimateItem& item : estimate_items()) item.set(fixed, false);
  fixed.gauge = Gauge::kNone;  // the model's anchors fix the world frame
  fixed.home_at_commanded = false;
  fixed.compute_covariance = false;
  fixed.refuse_unidentifiable = false;
  fixed.progress = {};
  CalibratedModel m{model, readings_of(model, made_with)};
  auto r = identify(m, tensions_read_with(set, made_with, model), fixed);
  if (!r.ok()) return r.status();
  ModelPrediction p;
  p.channels = channels_of(*r);
  p.chi2 = r->chi2;
  p.residuals = r->num_residuals;
  p.dof = r->dof;
  p.converged = r->converged;
  p.poses = r->poses;
  return p;
}

bool beats(const ModelPrediction& candidate, const ModelPrediction& reference, std::string* why) {
  const bool better = candidate.chi2 < reference.chi2;
  if (why != nullptr) {
    char buf[200];
    std::snprintf(buf, sizeof(buf), "held-out chi-square %.1f against the reference's %.1f",
                  candidate.chi2, reference.chi2);
    *why = buf;
    for (const ChannelPrediction& c : candidate.channels) {
      for (const ChannelPrediction& r : reference.channels) {
        if (r.channel != c.channel) continue;
        std::snprintf(buf, sizeof(buf), "; %s %.3g -> %.3g sigmas", c.channel.c_str(),
                      r.rms_normalized, c.rms_normalized);
        *why += buf;
      }
    }
  }
  return better;
}

}  // namespace cdpr
