"""Hierarchical radiosity on the split trees (SPEC §8): links between nodes, push-pull solve."""
