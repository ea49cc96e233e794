"""Probabilistic certificates for learned value functions (scenario optimization over HJI rollouts).

- :mod:`.bound`: the binomial (Clopper-Pearson) bound on a violation probability.
- :mod:`.truth`: exact failure margins (PyBullet geometry for arm pairs, analytic ``l`` otherwise).
- :mod:`.adversaries`: the disturbance strategies a certificate holds against.
- :mod:`.rollout`: closed-loop rollouts under the learned safe control.
- :mod:`.distributions`: uniform and visited-state distributions, level-set sampling.
- :mod:`.certify`: the δ search and the certificate; :mod:`.cards`: certificates in model cards.
- :mod:`.cli`: ``nehmo verify``; :mod:`.report`: Markdown.
"""

from nehmo_core.verify.bound import max_violations, violation_bound
from nehmo_core.verify.certify import Certificate, VerifySettings, certify

__all__ = ["Certificate", "VerifySettings", "certify", "max_violations", "violation_bound"]
