"""cores/localisation"""
