"""Statistics over an adjustment: ``distributions`` (critical values, δ0, B-method),
``hypotheses`` (alternative hypotheses and their tests), ``snooping``, ``robust``, ``variance``
(components), ``precision`` (covariances, ellipses, criterion matrices) and ``risk``."""
