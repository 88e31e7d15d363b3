// Model (Sep, d=p=1) of Hanebeck & Czado, Sec. IV, model 2:
//   z_t = b x_t + sqrt(1 - b^2) eps_t,
//   x_t = a x_{t-1} + sqrt(1 - a^2) eta_t,   eps_t, eta_t ~ N(0, 1) iid.
// Log posterior pi(Theta | z) of Theta = (a, b, x0, x_1..x_T) as in Sec. IV,
// model 2: flat priors on a and b over their prior intervals intersected
// with (-1, 1) (Eq. (3) for the restricted prior) and a flat, improper
// prior on x0.
data {
  int<lower=1> T;  // number of time steps
  vector[T] z;  // observations z_1..z_T
  real a_lower;  // lower bound of the flat prior on a (may be -inf)
  real<lower=a_lower> a_upper;  // upper bound of that prior (may be +inf)
  real b_lower;  // lower bound of the flat prior on b (may be -inf)
  real<lower=b_lower> b_upper;  // upper bound of that prior (may be +inf)
}
transformed data {
  real a_lo = fmax(a_lower, -1);  // support of a: prior interval
  real a_hi = fmin(a_upper, 1);  // intersected with (-1, 1)
  real b_lo = fmax(b_lower, -1);  // support of b: prior interval
  real b_hi = fmin(b_upper, 1);  // intersected with (-1, 1)
  if (!(a_lo < a_hi)) {
    reject("empty support for a: (", a_lo, ", ", a_hi, ")");
  }
  if (!(b_lo < b_hi)) {
    reject("empty support for b: (", b_lo, ", ", b_hi, ")");
  }
}
parameters {
  real<lower=a_lo, upper=a_hi> a;  // AR coefficient of the states
  real<lower=b_lo, upper=b_hi> b;  // loading of the observations
  real x0;  // initial state x_0
  vector[T] x;  // states x_1..x_T
}
model {
  z ~ normal(b * x, sqrt(1 - square(b)));
  x ~ normal(a * append_row(x0, head(x, T - 1)), sqrt(1 - square(a)));
}
