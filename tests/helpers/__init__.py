"""Helpers shared by the tests (one copy each): import them as ``tests.helpers.<module>``.

Tests never import from other test modules; what two test files need goes here.
"""
