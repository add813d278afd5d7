"""cores/association"""
