"""The generic identification core: it knows no valve and no loop (tests/test_import_graph.py).

* :mod:`~valve_env.ident.sde`: parameters, their transforms, continuous-discrete SDE models;
* :mod:`~valve_env.ident.kalman`: the EKF, the LKF, the RTS smoother, the scalar OU filter;
* :mod:`~valve_env.ident.mle`: the estimator interface and the maximum-likelihood estimator;
* :mod:`~valve_env.ident.uncertainty`: the finite-difference Hessian, the identified inverse, HAC and
  sandwich covariances;
* :mod:`~valve_env.ident.bootstrap`: the bootstrap driver;
* :mod:`~valve_env.ident.tests`: the noise level from second differences, the likelihood-ratio test (boundary
  mixture, effective sample size),
  BIC, whiteness (Ljung-Box) and the misspecification check;
* :mod:`~valve_env.ident.examples`: small example models (ctsmTMB's Ornstein-Uhlenbeck models).
"""
