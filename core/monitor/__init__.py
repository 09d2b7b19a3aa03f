"""core/monitor"""
