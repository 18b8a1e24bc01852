"""What happens at a guard (paper Fig. 3, Eqs. 21-43): contacts and their laws, guards, joint
cutting, the impulse, momenta, the event record, the transitions and the locks they hold."""
