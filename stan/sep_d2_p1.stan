// Model (Sep, d=2, p=1) of Hanebeck & Czado, Sec. IV, model 3:
//   z_{t,1} = a x_t + sqrt(1 - a^2) eps_{t,1},
//   z_{t,2} = b x_t + sqrt(1 - b^2) eps_{t,2},
//   x_t = c x_{t-1} + sqrt(1 - c^2) eta_t,   eps_t, eta_t ~ N(0, I) iid.
// Log posterior pi(Theta | z) of Theta = (a, b, c, x0, x_1..x_T) as in
// Sec. IV, model 3: flat priors on a, b, c over their prior intervals
// intersected with (-1, 1) (Eq. (3) for the restricted prior) and a flat,
// improper prior on x0.
data {
  int<lower=1> T;  // number of time steps
  matrix[T, 2] z;  // observations: row t is (z_{t,1}, z_{t,2})
  real a_lower;  // lower bound of the flat prior on a (may be -inf)
  real<lower=a_lower> a_upper;  // upper bound of that prior (may be +inf)
  real b_lower;  // lower bound of the flat prior on b (may be -inf)
  real<lower=b_lower> b_upper;  // upper bound of that prior (may be +inf)
  real c_lower;  // lower bound of the flat prior on c (may be -inf)
  real<lower=c_lower> c_upper;  // upper bound of that prior (may be +inf)
}
transformed data {
  real a_lo = fmax(a_lower, -1);  // support of a: prior interval
  real a_hi = fmin(a_upper, 1);  // intersected with (-1, 1)
  real b_lo = fmax(b_lower, -1);  // support of b: prior interval
  real b_hi = fmin(b_upper, 1);  // intersected with (-1, 1)
  real c_lo = fmax(c_lower, -1);  // support of c: prior interval
  real c_hi = fmin(c_upper, 1);  // intersected with (-1, 1)
  if (!(a_lo < a_hi)) {
    reject("empty support for a: (", a_lo, ", ", a_hi, ")");
  }
  if (!(b_lo < b_hi)) {
    reject("empty support for b: (", b_lo, ", ", b_hi, ")");
  }
  if (!(c_lo < c_hi)) {
    reject("empty support for c: (", c_lo, ", ", c_hi, ")");
  }
}
parameters {
  real<lower=a_lo, upper=a_hi> a;  // loading of the first observation
  real<lower=b_lo, upper=b_hi> b;  // loading of the second observation
  real<lower=c_lo, upper=c_hi> c;  // AR coefficient of the states
  real x0;  // initial state x_0
  vector[T] x;  // states x_1..x_T
}
model {
  col(z, 1) ~ normal(a * x, sqrt(1 - square(a)));
  col(z, 2) ~ normal(b * x, sqrt(1 - square(b)));
  x ~ normal(c * append_row(x0, head(x, T - 1)), sqrt(1 - square(c)));
}
