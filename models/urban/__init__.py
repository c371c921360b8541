"""Urban traffic (thesis chapters 3-4): SUMO scenarios, the multi-agent env over libsumo, route-agent DDQN."""
