"""The live 3-D view in the browser and the replay of recorded flights."""
