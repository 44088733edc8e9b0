"""The joint-path NLP: symbolic kinematics, constraints and the IPOPT solve (CasADi)."""
