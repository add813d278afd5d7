"""cores"""
