"""The audio error advisory: Equation 2 and the rotation rule, the generator and player processes, and the
WAV renderer."""
