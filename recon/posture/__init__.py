"""Posture estimation (paper section 2.1): the body model of cylinders, elliptic columns and hemispheres fitted to the cloud."""
