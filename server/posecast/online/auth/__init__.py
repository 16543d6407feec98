"""Join tokens: minting (the game backend, ``posecast token``) and verification."""
