"""drivers/assembly"""
