// Stochastic volatility model (not in Hanebeck & Czado; see
// workflow/ssmobs/models/stoch_vol.py):
//   x_t = mu + phi (x_{t-1} - mu) + sigma eta_t,   z_t = exp(x_t / 2) eps_t,
// eta_t, eps_t ~ N(0, 1) iid, mu = 0 fixed.  Log posterior of
// Theta = (phi, sigma, x0, x_1..x_T): flat priors on phi over
// (phi_lower, phi_upper) and on sigma over (sigma_lower, sigma_upper)
// intersected with sigma > 0, and a flat, improper prior on x0.
data {
  int<lower=1> T;  // number of time steps
  vector[T] z;  // observations (returns) z_1..z_T
  real phi_lower;  // bounds of the flat prior on phi
  real<lower=phi_lower> phi_upper;
  real sigma_lower;  // bounds of the flat prior on sigma (upper may be +inf)
  real<lower=sigma_lower> sigma_upper;
}
transformed data {
  real mu = 0;  // fixed level of the log-variance
  real sigma_lo = fmax(sigma_lower, 0);  // support of sigma: prior interval and sigma > 0
  if (!(sigma_lo < sigma_upper)) {
    reject("empty support for sigma: (", sigma_lo, ", ", sigma_upper, ")");
  }
}
parameters {
  real<lower=phi_lower, upper=phi_upper> phi;  // persistence of the log-variance
  real<lower=sigma_lo, upper=sigma_upper> sigma;  // volatility of the log-variance
  real x0;  // initial state x_0
  vector[T] x;  // log-variances x_1..x_T
}
model {
  z ~ normal(0, exp(x / 2));
  x ~ normal(mu + phi * (append_row(x0, head(x, T - 1)) - mu), sigma);
}
