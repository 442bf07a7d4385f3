"""``ilcpmac run``: identification, compensation and ILC phases, persisted trial by trial."""
