"""The paper's highway scenario: geometry, parameters, observation, reward, safety index, env."""
