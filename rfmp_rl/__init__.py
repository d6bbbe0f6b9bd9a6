"""rfmp_rl."""
