"""cores/filters"""
