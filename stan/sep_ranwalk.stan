// Model (Sep, d=p=1, ranWalk) of Hanebeck & Czado, Sec. IV, model 5;
// Eq. (8):
//   z_t = a x_t + eps_t,   x_t = x_{t-1} + eta_t,   eps_t, eta_t ~ N(0, 1).
// Log posterior pi(Theta | z) of Theta = (a, x0, x_1..x_T): Eq. (13), with
// a flat prior on a over (a_lower, a_upper) (Eq. (3) or the half line of
// Eq. (14)) and a flat, improper prior on x0.
data {
  int<lower=1> T;  // number of time steps
  vector[T] z;  // observations z_1..z_T
  real a_lower;  // lower bound of the flat prior on a (may be -inf)
  real<lower=a_lower> a_upper;  // upper bound of that prior (may be +inf)
}
parameters {
  real<lower=a_lower, upper=a_upper> a;  // loading of the observations
  real x0;  // initial state x_0
  vector[T] x;  // states x_1..x_T
}
model {
  z ~ normal(a * x, 1);
  x ~ normal(append_row(x0, head(x, T - 1)), 1);
}
