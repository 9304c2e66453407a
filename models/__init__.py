"""What is learned or simulated: pose backends, the boxer humanoid, and MAAIP (its arena,
environment, networks, losses and demonstrations)."""
