"""rfmp_rl: Riemannian Flow Matching Policies (RFMP, SRFMP) for TorchRL."""

__version__ = "0.1.0"
