"""Recording formats; ``load``/``save`` dispatch by suffix (see :mod:`rdnet.events.io.dispatch`)."""
