"""core/plant"""
