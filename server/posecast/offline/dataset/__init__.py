"""Training data: canonical clips turned into trackers, features and contact labels."""
