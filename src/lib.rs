pub mod cli; 
