"""The joint-path NLP: symbolic kinematics, constraints and the solve (CasADi; IPOPT, or fatrop)."""
