"""The models: frozen data read from files and the :class:`~baarda.model.problem.Problem` they become.

``problem`` (observations, parameters, covariance), ``network`` (geodetic networks), ``bundle``
(bundle blocks with additional parameters), ``imodel`` (independent-model blocks), ``sfm``
(structure-from-motion blocks from BAL, Bundler and COLMAP).
"""
