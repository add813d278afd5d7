"""cores/array"""
