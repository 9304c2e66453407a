"""What is learned or simulated: pose backends now; the humanoid, arena and networks later."""
