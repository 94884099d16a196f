// cdpr-fit validate: models (nominal, calibrated, diagnosed) predicting a held-out recording,
// each with the recording's poses re-fitted and the model fixed (model_validation.hpp).
#include <cmath>
#include <cstdio>
#include <sstream>

#include "cdpr/calibration/model_validation.hpp"
#include "cdpr/recording/recording.hpp"
#include "commands.hpp"
#include "common.hpp"

namespace cdpr::fit {

namespace {

// People's unit and factor of an SI channel unit.
std::pair<const char*, double> display_unit(const std::string& si) {
  if (si == "m") return {"mm", 1e3};
  if (si == "rad") return {"mrad", 1e3};
  return {"N", 1.0};
}

nlohmann::json prediction_json(const std::string& file, const ModelPrediction& p) {
  nlohmann::json j;
  j["model"] = file;
  j["chi2"] = p.chi2;
  j["residuals"] = p.residuals;
  j["dof"] = p.dof;
  j["converged"] = p.converged;
  j["channels"] = nlohmann::json::array();
  for (const ChannelPrediction& c : p.channels) {
    j["channels"].push_back({{"channel", c.channel},
                             {"unit", c.unit},
                             {"rows", c.rows},
                             {"rms", c.rms},
                             {"rms_normalized", c.rms_normalized}});
  }
  return j;
}

}  // namespace

Result<MeasurementSet> load_held_out(const RobotModel& made_with, const std::string& config,
                                     const std::string& file, const NoiseOverrides& noise,
                                     std::vector<std::string>* warnings) {
  auto rec = recording::read_recording(file);
  if (!rec.ok()) return rec.status();
  if (Status s = recording::check_against_model(*rec, made_with); !s.ok()) {
    return with_context(s, file + " vs " + config);
  }
  CDPR_RETURN_IF_ERROR(recording::check_plausible(*rec, made_with, file));
  auto set = recording::to_measurement_set(*rec);
  if (!set.ok()) return with_context(set.status(), file);
  apply_noise_overrides(noise, *rec, file, &*set, warnings);
  if (Status s = validate(*set, made_with); !s.ok()) return with_context(s, file);
  return set;
}

Result<HeldOut> held_out_predictions(const RobotModel& made_with, const MeasurementSet& set,
                                     const std::vector<NamedModel>& models) {
  HeldOut out;
  for (const auto& [name, model] : models) {
    if (model.num_cables() != made_with.num_cables() ||
        model.lasers.size() != made_with.lasers.size()) {
      return Status::error(ErrorCode::kInvalidArgument,
                           "%s has %d cables and %zu lasers, the recording's config %d and %zu",
                           name.c_str(), model.num_cables(), model.lasers.size(),
                           made_with.num_cables(), made_with.lasers.size());
    }
    auto p = predict_recording(model, made_with, set);
    if (!p.ok()) return with_context(p.status(), "predicting the held-out recording with " + name);
    out.models.push_back(name);
    out.predictions.push_back(std::move(*p));
  }
  return out;
}

std::string held_out_table(const HeldOut& h) {
  std::ostringstream os;
  char buf[160];
  std::snprintf(buf, sizeof(buf), "%-18s %-5s", "channel (RMS)", "unit");
  os << buf;
  for (std::size_t k = 0; k < h.models.size(); ++k) {
    std::snprintf(buf, sizeof(buf), " %14s", ("model " + std::to_string(k + 1)).c_str());
    os << buf;
  }
  os << "\n";
  if (h.predictions.empty()) return os.str();
  for (const ChannelPrediction& c0 : h.predictions.front().channels) {
    const auto [unit, factor] = display_unit(c0.unit);
    std::snprintf(buf, sizeof(buf), "%-18s %-5s", c0.channel.c_str(), unit);
    os << buf;
    for (const ModelPrediction& p : h.predictions) {
      double v = std::nan("");
      for (const ChannelPrediction& c : p.channels) {
        if (c.channel == c0.channel) v = c.rms * factor;
      }
      std::snprintf(buf, sizeof(buf), " %14.4g", v);
      os << buf;
    }
    os << "\n";
  }
  std::snprintf(buf, sizeof(buf), "%-18s %-5s", "chi2 / residuals", "-");
  os << buf;
  for (const ModelPrediction& p : h.predictions) {
    std::snprintf(buf, sizeof(buf), " %14.4g", p.residuals ? p.chi2 / p.residuals : 0.0);
    os << buf;
  }
  os << "\n";
  for (std::size_t k = 0; k < h.models.size(); ++k) {
    os << "model " << k + 1 << ": " << h.models[k] << "\n";
  }
  return os.str();
}

nlohmann::json held_out_json(const std::string& recording_file, const HeldOut& h) {
  nlohmann::json j;
  j["recording"] = recording_file;
  j["recording_hash"] = hash_or_unknown(recording_file);
  j["models"] = nlohmann::json::array();
  for (std::size_t k = 0; k < h.models.size(); ++k) {
    j["models"].push_back(prediction_json(h.models[k], h.predictions[k]));
  }
  return j;
}

Result<Output> validate_models(const ValidateArgs& args) {
  if (args.models.empty()) {
    return Status(ErrorCode::kInvalidArgument, "validate: give at least one --model");
  }
  std::vector<std::string> warnings;
  auto made_with = load_config(args.config);
  if (!made_with.ok()) return made_with.status();
  auto set = load_held_out(*made_with, args.config, args.recording, args.noise, &warnings);
  if (!set.ok()) return set.status();
  std::vector<NamedModel> models;
  for (const std::string& file : args.models) {
    auto model = load_config(file);
    if (!model.ok()) return model.status();
    models.emplace_back(file, std::move(*model));
  }
  auto h = held_out_predictions(*made_with, *set, models);
  if (!h.ok()) return h.status();
  Output out;
  out.json = held_out_json(args.recording, *h);
  out.json["config"] = args.config;
  out.json["warnings"] = warnings;
  std::ostringstream os;
  os << "held-out prediction of " << args.recording
     << " (poses re-fitted, every model fixed; readings made with " << args.config << ")\n";
  os << held_out_table(*h);
  for (const std::string& w : warnings) os << "warning: " << w << "\n";
  out.human = os.str();
  return out;
}

}  // namespace cdpr::fit
