"""Ground truth and accuracy: Mitsuba references, image comparison, accuracy-against-time studies."""
