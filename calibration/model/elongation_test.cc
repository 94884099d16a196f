#include "cdpr/calibration/elongation.hpp"

#include <ceres/jet.h>
#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

namespace cdpr {
namespace {

CableModel hooke(double ea) {
  CableModel c;
  c.ea = ea;
  c.elongation = ElongationKind::kHooke;
  return c;
}

// A surface written in plain (unscaled) variables: dL = sum c_ij L^i F^j.
double plain_polynomial(const std::vector<double>& c, int order, double l, double f) {
  double v = 0.0;
  std::size_t k = 0;
  for (int degree = 0; degree <= order; ++degree) {
    for (int j = 0; j <= degree; ++j, ++k) v += c[k] * std::pow(l, degree - j) * std::pow(f, j);
  }
  return v;
}

TEST(Elongation, RigidCablesDoNotStretch) {
  CableModel c;
  c.elongation = ElongationKind::kRigid;
  EXPECT_EQ(cable_elongation(c, 2.0, 300.0), 0.0);
  EXPECT_EQ(*loaded_length_from_unstretched(c, 2.0, 300.0), 2.0);
}

TEST(Elongation, HookeInTermsOfTheLoadedLength) {
  const CableModel c = hooke(2.0e4);
  for (const double l0 : {0.3, 1.0, 12.0}) {
    for (const double f : {0.0, 10.0, 150.0, 900.0}) {
      const double loaded = l0 * (1.0 + f / c.ea);  // L = L0 (1 + F / EA)
      const double dl = cable_elongation(c, loaded, f);
      EXPECT_NEAR(dl, f * l0 / c.ea, 1e-15);  // = F L0 / EA
      EXPECT_NEAR(loaded - dl, l0, 1e-15);
      EXPECT_NEAR(*loaded_length_from_unstretched(c, l0, f), loaded, 1e-15);
    }
  }
}

void expect_derivatives_match(const CableModel& c, double l, double f) {
  const ElongationDerivatives d = cable_elongation_derivatives(c, l, f);
  EXPECT_NEAR(d.elongation, cable_elongation(c, l, f), 1e-16);
  const double hl = 1e-6;
  const double hf = 1e-4;
  EXPECT_NEAR(d.d_length,
              (cable_elongation(c, l + hl, f) - cable_elongation(c, l - hl, f)) / (2 * hl), 1e-9);
  EXPECT_NEAR(d.d_tension,
              (cable_elongation(c, l, f + hf) - cable_elongation(c, l, f - hf)) / (2 * hf), 1e-11);
  using Jet = ceres::Jet<double, 2>;
  const Jet e = cable_elongation<Jet>(c, Jet(l, 0), Jet(f, 1));
  EXPECT_NEAR(e.a, d.elongation, 1e-16);
  EXPECT_NEAR(e.v(0), d.d_length, 1e-14);
  EXPECT_NEAR(e.v(1), d.d_tension, 1e-16);
}

PolynomialSurface example_surface() {
  PolynomialSurface p;
  p.order = 3;
  p.length_center = 1.5;
  p.length_scale = 1.0;
  p.tension_center = 100.0;
  p.tension_scale = 90.0;
  p.coefficients = {3e-3, 1.5e-3, 4e-3, 1e-4, 2e-3, -6e-4, 5e-5, -1e-4, -3e-4, 1e-4};
  return p;
}

TEST(Elongation, DerivativesAreExact) {
  expect_derivatives_match(hooke(2.0e4), 1.3, 120.0);
  CableModel poly;
  poly.elongation = ElongationKind::kPolynomial;
  poly.polynomial = example_surface();
  expect_derivatives_match(poly, 0.9, 40.0);
  expect_derivatives_match(poly, 2.4, 170.0);
}

TEST(Elongation, PolynomialUsesTheDocumentedGradedOrder) {
  // Default scaling (0, 1, 0, 1) is the plain form of robot_model.hpp.
  PolynomialSurface p;
  p.order = 2;
  p.coefficients.assign(6, 0.0);
  p.coefficients[4] = 1.0;  // degree 2: (i=2, j=0), (1, 1), (0, 2) -> index 4 is L F
  EXPECT_DOUBLE_EQ(polynomial_surface_value(p, 1.7, 30.0), 1.7 * 30.0);
  p.coefficients[4] = 0.0;
  p.coefficients[2] = 1.0;  // degree 1: (1, 0), (0, 1) -> index 2 is F
  EXPECT_DOUBLE_EQ(polynomial_surface_value(p, 1.7, 30.0), 30.0);
  // A full random surface equals the brute-force sum.
  std::mt19937_64 rng(4);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  p.order = 4;
  p.coefficients.resize(static_cast<std::size_t>(polynomial_surface_size(4)));
  for (double& c : p.coefficients) c = u(rng);
  EXPECT_NEAR(polynomial_surface_value(p, 0.8, -0.6),
              plain_polynomial(p.coefficients, 4, 0.8, -0.6), 1e-14);
  EXPECT_TRUE(validate_polynomial_surface(p).ok());
  p.coefficients.pop_back();
  EXPECT_EQ(validate_polynomial_surface(p).code(), ErrorCode::kInvalidArgument);
}

TEST(Elongation, LoadedLengthInvertsThePolynomial) {
  CableModel c;
  c.elongation = ElongationKind::kPolynomial;
  c.polynomial = example_surface();
  for (const double l0 : {0.6, 1.5, 2.3}) {
    for (const double f : {10.0, 100.0, 190.0}) {
      const Result<double> l = loaded_length_from_unstretched(c, l0, f);
      ASSERT_TRUE(l.ok()) << l.status().to_string();
      EXPECT_NEAR(*l - cable_elongation(c, *l, f), l0, 1e-13);
    }
  }
  // A surface that shrinks faster than the cable grows has no inverse: a clear failure.
  c.polynomial.coefficients[1] = 2.0;  // d(dL)/dL = 2 > 1
  const Result<double> bad = loaded_length_from_unstretched(c, 1.0, 50.0);
  EXPECT_EQ(bad.status().code(), ErrorCode::kNumericalFailure);
}

// Samples on a grid of lengths and tensions (as on an elongation bench), with noise.
std::vector<ElongationSample> bench_samples(const CableModel& truth, double noise,
                                            std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n(0.0, noise);
  std::vector<ElongationSample> s;
  for (int i = 0; i < 12; ++i) {
    for (int j = 0; j < 10; ++j) {
      const double l = 0.5 + 2.5 * i / 11.0;
      const double f = 5.0 + 195.0 * j / 9.0;
      s.push_back({l, f, cable_elongation(truth, l, f) + (noise > 0 ? n(rng) : 0.0)});
    }
  }
  return s;
}

TEST(ElongationFit, RecoversAnExactSurface) {
  CableModel truth;
  truth.elongation = ElongationKind::kPolynomial;
  truth.polynomial = example_surface();
  const std::vector<ElongationSample> samples = bench_samples(truth, 0.0, 1);
  PolynomialFitOptions options;
  options.min_order = 3;
  options.max_order = 3;
  const Result<PolynomialFitSummary> fit = fit_polynomial_surface(samples, options);
  ASSERT_TRUE(fit.ok()) << fit.status().to_string();
  EXPECT_EQ(fit->order, 3);
  CableModel fitted = truth;
  fitted.polynomial = fit->surface;
  for (const double l : {0.7, 1.9, 2.8}) {
    for (const double f : {8.0, 77.0, 199.0}) {
      EXPECT_NEAR(cable_elongation(fitted, l, f), cable_elongation(truth, l, f), 1e-14);
    }
  }
  EXPECT_LT(fit->training_rmse, 1e-15);
}

TEST(ElongationFit, CrossValidationPicksTheTrueOrderAndReportsEveryOrder) {
  CableModel truth;
  truth.elongation = ElongationKind::kPolynomial;
  truth.polynomial = example_surface();  // order 3
  const double noise = 2e-5;             // 20 um bench noise
  const std::vector<ElongationSample> samples = bench_samples(truth, noise, 2);
  PolynomialFitOptions options;  // orders 1..5, 5 folds, one-standard-error rule
  const Result<PolynomialFitSummary> fit = fit_polynomial_surface(samples, options);
  ASSERT_TRUE(fit.ok()) << fit.status().to_string();
  ASSERT_EQ(fit->orders.size(), 5u);
  ASSERT_EQ(fit->cv_rmse.size(), 5u);
  ASSERT_EQ(fit->cv_rmse_stderr.size(), 5u);
  EXPECT_EQ(fit->order, 3);
  // Orders 1 and 2 miss the cubic terms by far more than the noise; 3..5 reach the noise.
  EXPECT_GT(fit->cv_rmse[0], 10 * noise);
  EXPECT_GT(fit->cv_rmse[1], 3 * noise);
  for (std::size_t k = 2; k < 5; ++k) EXPECT_LT(fit->cv_rmse[k], 1.5 * noise);
  EXPECT_NEAR(fit->training_rmse, noise, 0.3 * noise);
  // Scaled variables keep the problem well conditioned (a raw Vandermonde in L [m] and F [N]
  // of order 5 would be near 1e12).
  EXPECT_LT(fit->condition_number, 1e3);
}

TEST(ElongationFit, FitsHookeData) {
  // Hooke is F L / (EA + F): close to the degree-2 term F L; the fit reaches the noise.
  const CableModel truth = hooke(2.0e4);
  const double noise = 1e-5;
  const std::vector<ElongationSample> samples = bench_samples(truth, noise, 3);
  const Result<PolynomialFitSummary> fit = fit_polynomial_surface(samples);
  ASSERT_TRUE(fit.ok()) << fit.status().to_string();
  EXPECT_GE(fit->order, 2);
  EXPECT_LT(fit->training_rmse, 1.3 * noise);
}

TEST(ElongationFit, RefusesDegenerateData) {
  const CableModel truth = hooke(2.0e4);
  std::vector<ElongationSample> one_length;
  for (int j = 0; j < 30; ++j)
    one_length.push_back({1.0, 5.0 + j, cable_elongation(truth, 1.0, 5.0 + j)});
  Result<PolynomialFitSummary> r = fit_polynomial_surface(one_length);
  EXPECT_EQ(r.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("same length"), std::string_view::npos);

  std::vector<ElongationSample> few = bench_samples(truth, 0.0, 1);
  few.resize(4);
  r = fit_polynomial_surface(few);
  EXPECT_EQ(r.status().code(), ErrorCode::kInvalidArgument);

  std::vector<ElongationSample> nan = bench_samples(truth, 0.0, 1);
  nan[7].elongation = std::numeric_limits<double>::quiet_NaN();
  r = fit_polynomial_surface(nan);
  EXPECT_EQ(r.status().code(), ErrorCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("sample 7"), std::string_view::npos);

  PolynomialFitOptions bad;
  bad.folds = 1;
  EXPECT_EQ(fit_polynomial_surface(bench_samples(truth, 0.0, 1), bad).status().code(),
            ErrorCode::kInvalidArgument);
  bad = {};
  bad.max_order = kMaxPolynomialOrder + 1;
  EXPECT_EQ(fit_polynomial_surface(bench_samples(truth, 0.0, 1), bad).status().code(),
            ErrorCode::kInvalidArgument);

  // Only two tensions: order >= 2 in F is not identifiable (reported as infinite CV error),
  // order 1 still is.
  std::vector<ElongationSample> two_tensions;
  for (int i = 0; i < 20; ++i) {
    for (const double f : {10.0, 100.0}) {
      const double l = 0.5 + 0.1 * i;
      two_tensions.push_back({l, f, cable_elongation(truth, l, f)});
    }
  }
  PolynomialFitOptions o;
  o.min_order = 1;
  o.max_order = 3;
  const Result<PolynomialFitSummary> partial = fit_polynomial_surface(two_tensions, o);
  ASSERT_TRUE(partial.ok()) << partial.status().to_string();
  EXPECT_EQ(partial->order, 1);
  EXPECT_TRUE(std::isfinite(partial->cv_rmse[0]));
  EXPECT_TRUE(std::isinf(partial->cv_rmse[1]));
}

}  // namespace
}  // namespace cdpr
