"""Training: the shared optimisation loop of image-trained fields, and image metrics."""
