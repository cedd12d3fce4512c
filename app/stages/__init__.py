"""The pipeline's stages, one of each for every method: preprocess, solve, image."""
