"""Test doubles, stand-ins and frozen oracles used by the tests (and by a few benchmarks as
baselines). Product code never imports from here.
"""
