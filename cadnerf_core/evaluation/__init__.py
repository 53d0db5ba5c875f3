"""Evaluation: synthetic datasets with true cameras, image and pose metrics, the protocol."""
